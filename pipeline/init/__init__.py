"""The initial estimate of a sequence (`harp init`): MediaPipe keypoints, a keypoint file, or
the ground truth with noise, fitted by the hand model into init.npz.

    from pipeline.init import initialise_sequence
    initialise_sequence("clip", "mediapipe")
"""
from .initialisation import METHODS, initialise_sequence

__all__ = ["initialise_sequence", "METHODS"]
