"""The fitted environment light in Blender (Cycles as the reference): the world the bind makes
from an avatar's ambient ratio and spherical-harmonic environment (harp_addon/scene.py) lights a
white Lambertian sphere as the fit's shading factor a + sum_k c_k Y_k(n) says
(formats/environment_light.py), in the capture space's orientation."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from cycles_sphere import render_sphere, sphere_normals  # noqa: E402
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
    """(H, W, 3) linear radiance of a white diffuse unit sphere lit by the world the bind makes
    of `ambient` and `coefficients` alone (cycles_sphere.py)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.scene.world = harp_scene._fitted_world("test", ambient, coefficients)
    material = bpy.data.materials.new("white")
    tree = harp_scene._node_tree(material)
    principled = next(node for node in tree.nodes if node.bl_idname == "ShaderNodeBsdfPrincipled")
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    output = next(node for node in tree.nodes if node.bl_idname == "ShaderNodeOutputMaterial")
    tree.links.new(diffuse.outputs["BSDF"], output.inputs["Surface"])
    tree.nodes.remove(principled)
    return render_sphere(material, SIZE, 256, tmp_path)


def test_the_bound_world_lights_the_skin_as_the_fit_does(tmp_path):
    coefficients, ambient = environment(), 0.5
    pixels = sphere_under_world(ambient, coefficients, tmp_path)
    inside, normals_world = sphere_normals(SIZE, 0.8)
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
