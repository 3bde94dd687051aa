"""Synthetic hand clips with exact ground truth, rendered headless with Cycles.

Entry points: `synth/render.py` (one clip) and `synth/dataset.py` (the standard evaluation
set). Needs only numpy and bpy, so it runs inside Blender's own Python
(`blender -b -P synth/render.py -- ARGS`) and with the bpy module (`python synth/render.py ARGS`).
Modules that touch bpy: material, lighting, passes, clip; the hand's rig is the Blender add-on's
(harp_addon/rig.py, one home for both). The others are plain numpy.
"""


class SynthError(Exception):
    """Bad settings or inputs; the command line prints its message as one line."""
