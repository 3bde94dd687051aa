"""The fitted environment light in Blender (Cycles as the reference): the world the bind makes
from an avatar's ambient ratio and spherical-harmonic environment (harp_addon/scene.py) lights a
white Lambertian sphere as the fit's shading factor a + sum_k c_k Y_k(n) says
(formats/environment_light.py), in the capture space's orientation."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from harp_addon import scene as harp_scene  # noqa: E402
from pipeline.formats import environment_light  # noqa: E402

pytestmark = pytest.mark.blender
SIZE = 24


def environment():
    """A coloured room: blue light from the camera's left, warm light from below, a brighter
    band around the camera's axis."""
    coefficients = np.zeros((environment_light.COEFFICIENTS, 3))
    coefficients[2] = -0.25 * np.array([0.3, 0.6, 1.0])     # Y ~ x: the left side (-x) brighter, bluer
    coefficients[0] = 0.15 * np.array([1.0, 0.7, 0.4])      # Y ~ y: from below (+y, OpenCV's down), warm
    coefficients[5] = 0.08                                   # Y ~ 3 z^2 - 1
    return coefficients


def sphere_under_world(ambient, coefficients, tmp_path):
    """(H, W, 3) linear radiance of a white diffuse unit sphere at the origin lit by the world the
    bind makes of `ambient` and `coefficients` alone,
    seen by an orthographic camera from world -Y (the capture camera's direction: looking along
    +Y, Z up), rendered by Cycles."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.world = harp_scene._fitted_world("test", ambient, coefficients)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=128, ring_count=64, radius=1.0)
    sphere = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    material = bpy.data.materials.new("white")
    tree = harp_scene._node_tree(material)
    principled = next(node for node in tree.nodes if node.bl_idname == "ShaderNodeBsdfPrincipled")
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    output = next(node for node in tree.nodes if node.bl_idname == "ShaderNodeOutputMaterial")
    tree.links.new(diffuse.outputs["BSDF"], output.inputs["Surface"])
    tree.nodes.remove(principled)
    sphere.data.materials.append(material)
    camera_data = bpy.data.cameras.new("camera")
    camera_data.type, camera_data.ortho_scale = "ORTHO", 2.0
    camera = bpy.data.objects.new("camera", camera_data)
    scene.collection.objects.link(camera)
    camera.location, camera.rotation_euler = (0.0, -5.0, 0.0), (np.pi / 2, 0.0, 0.0)
    scene.camera = camera
    scene.render.engine = "CYCLES"
    scene.cycles.samples, scene.cycles.use_denoising, scene.cycles.seed = 256, False, 0
    scene.cycles.max_bounces = 0
    scene.render.resolution_x = scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(tmp_path / "sphere.exr")
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(str(tmp_path / "sphere.exr"))
    pixels = np.array(image.pixels[:], dtype=np.float64).reshape(SIZE, SIZE, 4)[::-1, :, :3]   # row 0: the top
    return pixels


def test_the_bound_world_lights_the_skin_as_the_fit_does(tmp_path):
    coefficients, ambient = environment(), 0.5
    pixels = sphere_under_world(ambient, coefficients, tmp_path)
    # the visible sphere's normals (world: x right, z up, towards the camera -y), inside its rim
    centre = (np.arange(SIZE) + 0.5) / SIZE * 2 - 1
    z, x = -centre[:, None] * np.ones(SIZE), centre[None, :] * np.ones((SIZE, 1))
    inside = x ** 2 + z ** 2 < 0.8 ** 2
    normals_world = np.stack([x, -np.sqrt(np.clip(1 - x ** 2 - z ** 2, 0, None)), z], -1)[inside]
    normals_camera = normals_world @ harp_scene.CAPTURE_TO_WORLD[:3, :3]     # world -> camera: C^T n
    expected = ambient + environment_light.shading_factor(normals_camera, coefficients)
    error = np.abs(pixels[inside] - expected)
    assert error.mean() < 0.01 and np.percentile(error, 95) < 0.03, (error.mean(), np.percentile(error, 95))
    # and the environment matters: a plain world of the ambient ratio is far from it
    assert np.abs(pixels[inside] - ambient).mean() > 5 * error.mean()


def test_without_an_environment_the_world_is_the_ambient_share():
    world = harp_scene._fitted_world("plain", 0.4, None)
    background = next(node for node in world.node_tree.nodes if node.bl_idname == "ShaderNodeBackground")
    assert background.inputs["Strength"].default_value == pytest.approx(0.4)
    assert not any(node.bl_idname == "ShaderNodeTexEnvironment" for node in world.node_tree.nodes)
