"""Blender as an independent reference renderer for tests: Cycles renders the mask (alpha) and
camera-space depth of a mesh seen through an OpenCV camera, via pipeline.formats.camera.

One sample with a near-zero pixel filter samples each pixel at its centre, like our rasteriser.
"""
from __future__ import annotations

import os
import tempfile

import numpy as np

from pipeline.formats import camera


def render_mask_and_depth(vertices, faces, K, width, height):
    """(alpha (H, W) in [0, 1], depth (H, W) metres, inf where empty) of a mesh whose vertices are
    given in the OpenCV camera frame of a camera at the world origin (R = I, t = 0)."""
    import bpy

    scene = _fresh_scene()
    mesh = bpy.data.meshes.new("harp_mesh")
    mesh.from_pydata(np.asarray(vertices, dtype=np.float64).tolist(), [], np.asarray(faces).tolist())
    mesh.update()
    obj = bpy.data.objects.new("harp_mesh", mesh)
    scene.collection.objects.link(obj)
    obj.data.materials.append(_depth_material())

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
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.cycles.filter_width = 0.01
    scene.cycles.max_bounces = 0
    scene.render.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.image_settings.color_mode = "RGBA"
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "depth.exr")
        scene.render.filepath = path
        bpy.ops.render.render(write_still=True)
        image = bpy.data.images.load(path)
        pixels = np.array(image.pixels[:], dtype=np.float64).reshape(height, width, 4)[::-1]
        bpy.data.images.remove(image)
    alpha = pixels[..., 3]
    depth = np.where(alpha > 0.5, pixels[..., 0] / np.maximum(alpha, 1e-12), np.inf)
    return alpha, depth


def _fresh_scene():
    import bpy

    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    for collection in (bpy.data.meshes, bpy.data.cameras, bpy.data.materials):
        for item in list(collection):
            collection.remove(item)
    return bpy.context.scene


def _depth_material():
    """Emission shader whose colour is the camera-space depth (Camera Data: View Z Depth)."""
    import bpy

    material = bpy.data.materials.new("harp_depth")
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    nodes.clear()
    camera_data = nodes.new("ShaderNodeCameraData")
    emission = nodes.new("ShaderNodeEmission")
    output = nodes.new("ShaderNodeOutputMaterial")
    links.new(camera_data.outputs["View Z Depth"], emission.inputs["Color"])
    links.new(emission.outputs["Emission"], output.inputs["Surface"])
    return material
