"""A unit sphere at the origin in Cycles, seen by an orthographic camera from world -Y (the
capture camera's direction: looking along +Y, Z up), for the tests that check the bind's light
and material against the fit's formulas (bpy)."""
import bpy
import numpy as np


def render_sphere(material, size, samples, tmp_path):
    """(size, size, 3) linear radiance of a smooth unit sphere wearing `material` in the current
    scene (its world and lights as the caller set them), direct light only, row 0 at the top."""
    scene = bpy.context.scene
    bpy.ops.mesh.primitive_uv_sphere_add(segments=128, ring_count=64, radius=1.0)
    sphere = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    sphere.data.materials.append(material)
    camera_data = bpy.data.cameras.new("camera")
    camera_data.type, camera_data.ortho_scale = "ORTHO", 2.0
    camera = bpy.data.objects.new("camera", camera_data)
    scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (0.0, -5.0, 0.0), (np.pi / 2, 0.0, 0.0)
    scene.camera = camera
    return render_direct_light(size, samples, tmp_path / "sphere.exr")


def render_direct_light(size, samples, path):
    """(size, size, 3) linear radiance of the current scene from its camera, Cycles with direct
    light only and no denoising, written to `path` (EXR) and read back, row 0 at the top."""
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples, scene.cycles.use_denoising, scene.cycles.seed = samples, False, 0
    scene.cycles.max_bounces = 0
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(str(path))
    return np.array(image.pixels[:], dtype=np.float64).reshape(size, size, 4)[::-1, :, :3]


def sphere_normals(size, rim):
    """(inside (size, size) bool, world normals (N, 3)) of the visible sphere's pixels inside
    `rim` of its radius (world: x right, z up, towards the camera -y)."""
    centre = (np.arange(size) + 0.5) / size * 2 - 1
    z, x = -centre[:, None] * np.ones(size), centre[None, :] * np.ones((size, 1))
    inside = x ** 2 + z ** 2 < rim ** 2
    return inside, np.stack([x, -np.sqrt(np.clip(1 - x ** 2 - z ** 2, 0, None)), z], -1)[inside]
