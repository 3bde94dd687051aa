"""The formats the add-on reads and writes: pipeline/formats, the one source (numpy and the
standard library only; never torch, never OpenCV).

In the built extension they travel inside it as `harp_addon/vendor/formats` (the build copies
them there, nothing is committed twice); run from the project (tests, `harp blend`, synth)
they are imported from the installed pipeline package.
"""
try:  # the built extension
    from .vendor.formats import (avatar_folder, camera, environment_light, fit_report, hand_model_file,
                                  light_size, pose_smoothing, rotations, sequence_folder, specular_lobe)
except ImportError:  # the project itself
    from pipeline.formats import (avatar_folder, camera, environment_light, fit_report, hand_model_file,
                                  light_size, pose_smoothing, rotations, sequence_folder, specular_lobe)

__all__ = ["avatar_folder", "camera", "environment_light", "fit_report", "hand_model_file", "light_size",
           "pose_smoothing", "rotations", "sequence_folder", "specular_lobe"]
