"""Hand detection in images (MediaPipe, offline): the layer under `harp import-video` and
`harp init`. MediaPipe itself is imported only when a detector is made."""
from .mediapipe_hands import MediaPipeHands, detect_keypoints, detect_sequence_keypoints, guess_hand_side

__all__ = ["MediaPipeHands", "detect_keypoints", "detect_sequence_keypoints", "guess_hand_side"]
