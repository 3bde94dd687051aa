"""Render settings and the two passes of a frame (bpy): the Cycles colour image and the exact
binary mask of hand and arm.

The mask comes from a second scene that shares the hand collection and the camera: Workbench
with flat white shading on black and anti-aliasing off (one sample at each pixel centre, like
a rasteriser), or, where no OpenGL is available, Cycles with one sample, a 0.01 px pixel filter
and a white emission override. Both give only the values 0 and 255.
"""
from __future__ import annotations

import contextlib
import os
import sys

import bpy

from .material import flat_material
from .options import MASK_ENGINES


def configure_cycles(scene, samples, denoise, seed=0):
    """Low sample count + OpenImageDenoise on the CPU; short light paths (skin needs few)."""
    scene.render.engine = "CYCLES"
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.samples = samples
    cycles.use_adaptive_sampling = True
    cycles.adaptive_threshold = 0.02
    cycles.use_denoising = denoise
    if denoise:
        cycles.denoiser = "OPENIMAGEDENOISE"
        cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        cycles.denoising_prefilter = "FAST"
    cycles.max_bounces = 4
    cycles.diffuse_bounces = 2
    cycles.glossy_bounces = 1
    cycles.transmission_bounces = 0
    cycles.transparent_max_bounces = 0
    cycles.volume_bounces = 0
    cycles.caustics_reflective = cycles.caustics_refractive = False
    cycles.seed = seed
    scene.render.use_persistent_data = True
    _plain_output(scene, "RGB")


def _plain_output(scene, colour_mode):
    """8-bit PNG, plain sRGB display transform, no dithering."""
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.dither_intensity = 0.0
    scene.render.film_transparent = False
    settings = scene.render.image_settings
    settings.file_format = "PNG"
    settings.color_mode = colour_mode
    settings.color_depth = "8"
    settings.compression = 15


def make_mask_scene(source, hand_collection, camera, engine="workbench"):
    """A scene rendering `hand_collection` seen by `camera` as white on black."""
    if engine not in MASK_ENGINES:
        raise ValueError(f"unknown mask engine {engine!r}; choose one of {MASK_ENGINES}")
    scene = bpy.data.scenes.new("mask")
    scene.collection.children.link(hand_collection)
    scene.collection.objects.link(camera)
    scene.camera = camera
    scene.render.resolution_x = source.render.resolution_x
    scene.render.resolution_y = source.render.resolution_y
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    world = bpy.data.worlds.new("mask_world")
    world.color = (0.0, 0.0, 0.0)
    scene.world = world
    if engine == "workbench":
        scene.render.engine = "BLENDER_WORKBENCH"
        scene.display.render_aa = "OFF"
        shading = scene.display.shading
        shading.light = "FLAT"
        shading.color_type = "SINGLE"
        shading.single_color = (1.0, 1.0, 1.0)
        shading.background_type = "WORLD"
        for flag in ("show_object_outline", "show_cavity", "show_shadows", "show_specular_highlight",
                     "show_xray", "show_backface_culling", "use_dof"):
            setattr(shading, flag, False)
    else:
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = 1
        scene.cycles.use_adaptive_sampling = False
        scene.cycles.use_denoising = False
        scene.cycles.pixel_filter_type = "BOX"
        scene.cycles.filter_width = 0.01
        scene.cycles.max_bounces = 0
        scene.view_layers[0].material_override = flat_material("mask_white", (1.0, 1.0, 1.0))
        nodes = world.node_tree.nodes
        nodes["Background"].inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    _plain_output(scene, "BW")
    return scene


def render_still(scene, path, quiet=True):
    """Render `scene` and write its image to `path` (PNG)."""
    scene.render.filepath = str(path)
    with silenced(quiet):
        bpy.ops.render.render(write_still=True, scene=scene.name)


@contextlib.contextmanager
def silenced(quiet):
    """Hide Blender's per-render progress lines and its OpenGL/CUDA probing notes (written by C
    code straight to the stdout and stderr file descriptors). Errors still raise in Python."""
    if not quiet:
        yield
        return
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        os.dup2(null.fileno(), 2)
        try:
            yield
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            for fd, copy in zip((1, 2), saved):
                os.dup2(copy, fd)
                os.close(copy)
