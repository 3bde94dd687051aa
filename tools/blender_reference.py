"""Blender as an independent reference renderer (tests and pictures): Cycles renders the mask
(alpha) and camera-space depth of a mesh seen through an OpenCV camera, via
pipeline.formats.camera, and a shaded picture for side-by-side comparisons.

One sample with a near-zero pixel filter samples each pixel at its centre, like our rasteriser.
Needs the bpy module.
"""
from __future__ import annotations

import os
import tempfile

import numpy as np

from pipeline.formats import camera


def render_mask_and_depth(vertices, faces, K, width, height):
    """(alpha (H, W) in [0, 1], depth (H, W) metres, inf where empty) of a mesh whose vertices are
    given in the OpenCV camera frame of a camera at the world origin (R = I, t = 0)."""
    pixels = _render(vertices, faces, K, width, height, _depth_material(), samples=1, filter_width=0.01,
                     file_format="OPEN_EXR")
    alpha = pixels[..., 3]
    depth = np.where(alpha > 0.5, pixels[..., 0] / np.maximum(alpha, 1e-12), np.inf)
    return alpha, depth


def render_shaded(vertices, faces, K, width, height, light_position, colour=(0.8, 0.6, 0.5)):
    """(H, W, 4) RGBA in [0, 1]: Cycles, a diffuse material lit by a point light at
    `light_position` (camera frame) plus a grey world, for pictures."""
    import bpy

    material = bpy.data.materials.new("harp_diffuse")
    shader = material.node_tree.nodes.get("Principled BSDF")
    shader.inputs["Base Color"].default_value = (*colour, 1.0)
    shader.inputs["Roughness"].default_value = 1.0
    return _render(vertices, faces, K, width, height, material, samples=32, filter_width=1.5,
                   file_format="PNG", light_position=light_position)


def _render(vertices, faces, K, width, height, material, samples, filter_width, file_format, light_position=None):
    import bpy

    scene = _fresh_scene()
    mesh = bpy.data.meshes.new("harp_mesh")
    mesh.from_pydata(np.asarray(vertices, dtype=np.float64).tolist(), [], np.asarray(faces).tolist())
    mesh.update()
    obj = bpy.data.objects.new("harp_mesh", mesh)
    scene.collection.objects.link(obj)
    obj.data.materials.append(material)
    if light_position is not None:
        light = bpy.data.objects.new("harp_light", bpy.data.lights.new("harp_light", "POINT"))
        light.data.energy = 12.0
        light.data.shadow_soft_size = 0.0
        for polygon in mesh.polygons:
            polygon.use_smooth = True
        light.location = tuple(float(x) for x in light_position)  # world = our camera frame here
        scene.collection.objects.link(light)
        scene.world = scene.world or bpy.data.worlds.new("harp_world")
        scene.world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.25, 0.25, 0.25, 1.0)

    settings = camera.blender_camera_settings(K, width, height)
    data = bpy.data.cameras.new("harp_camera")
    for key, value in settings.items():
        setattr(data, key, value)
    data.clip_start, data.clip_end = 1e-3, 100.0
    cam = bpy.data.objects.new("harp_camera", data)
    scene.collection.objects.link(cam)
    from mathutils import Matrix
    cam.matrix_world = Matrix(camera.blender_camera_matrix_world(np.eye(3), np.zeros(3)).tolist())
    scene.camera = cam

    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.cycles.filter_width = filter_width
    scene.cycles.max_bounces = 0 if light_position is None else 2
    scene.render.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = file_format
    if file_format == "OPEN_EXR":
        scene.render.image_settings.color_depth = "32"
    scene.render.image_settings.color_mode = "RGBA"
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "render." + ("exr" if file_format == "OPEN_EXR" else "png"))
        scene.render.filepath = path
        bpy.ops.render.render(write_still=True)
        image = bpy.data.images.load(path)
        pixels = np.array(image.pixels[:], dtype=np.float64).reshape(height, width, 4)[::-1]
        bpy.data.images.remove(image)
    return pixels


def _fresh_scene():
    import bpy

    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    for collection in (bpy.data.meshes, bpy.data.cameras, bpy.data.lights):
        for item in list(collection):
            collection.remove(item)
    return bpy.context.scene


def _depth_material():
    """Emission shader whose colour is the camera-space depth (Camera Data: View Z Depth)."""
    import bpy

    material = bpy.data.materials.new("harp_depth")
    nodes, links = material.node_tree.nodes, material.node_tree.links
    nodes.clear()
    camera_data = nodes.new("ShaderNodeCameraData")
    emission = nodes.new("ShaderNodeEmission")
    output = nodes.new("ShaderNodeOutputMaterial")
    links.new(camera_data.outputs["View Z Depth"], emission.inputs["Color"])
    links.new(emission.outputs["Emission"], output.inputs["Surface"])
    return material
