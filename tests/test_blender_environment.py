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


@pytest.mark.parametrize("index", range(environment_light.COEFFICIENTS))
def test_each_harmonic_alone_lights_the_sphere_as_the_fit_does(index, tmp_path):
    """Each of the 8 harmonics on its own, so that a mirrored axis in the bake cannot hide behind
    the others (the world was once mirrored front to back: the harmonics odd in the camera's z,
    the direction it looks, came out with their signs turned)."""
    coefficients = np.zeros((environment_light.COEFFICIENTS, 3))
    coefficients[index] = 0.2
    pixels = sphere_under_world(0.5, coefficients, tmp_path)
    inside, normals_world = sphere_normals(SIZE, 0.8)
    normals_camera = normals_world @ harp_scene.CAPTURE_TO_WORLD[:3, :3]
    expected = 0.5 + environment_light.shading_factor(normals_camera, coefficients)
    error = np.abs(pixels[inside] - expected).mean()
    signal = np.abs(expected - 0.5).mean()
    assert error < 0.25 * signal, (error, signal)     # measured 0.10-0.12; mirrored: 2.0


def test_without_an_environment_the_world_is_the_ambient_share():
    world = harp_scene._fitted_world("plain", 0.4, None)
    background = next(node for node in world.node_tree.nodes if node.bl_idname == "ShaderNodeBackground")
    assert background.inputs["Strength"].default_value == pytest.approx(0.4)
    assert not any(node.bl_idname == "ShaderNodeTexEnvironment" for node in world.node_tree.nodes)


def bound_sun(light, transl):
    """The sun the bind makes of avatar.json's `light` for a hand at `transl` (F, 3), in a fresh
    scene whose capture space has the bind's orientation."""
    from types import SimpleNamespace

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    collection = bpy.data.collections.new("harp")
    scene.collection.children.link(collection)
    space = bpy.data.objects.new("space", None)
    collection.objects.link(space)
    space.matrix_world = harp_scene.Matrix(harp_scene.CAPTURE_TO_WORLD.tolist())
    files = SimpleNamespace(description={"light": light}, poses=SimpleNamespace(transl=np.asarray(transl)))
    return harp_scene._fitted_light("test", collection, space, files, scene)


@pytest.mark.parametrize("shadows", [False, True])
def test_the_bound_sun_shines_from_the_fitted_light_and_shadows_only_as_the_fit_did(shadows):
    """A fit without self-shadowing lit the hand's far side too: its sun casts no shadow then."""
    sun = bound_sun({"ambient": 0.3, "position": [0.1, -0.3, 0.2], "shadows": shadows},
                    [[0.0, 0.0, 0.4], [0.0, 0.02, 0.4]])
    assert sun.data.type == "SUN" and sun.data.use_shadow is shadows
    assert sun.data.energy == pytest.approx(np.pi * 0.7)
    bpy.context.view_layer.update()
    shining = -np.array(sun.matrix_world)[:3, 2]                         # a sun shines along its local -Z
    towards = np.array([0.0, 0.01, 0.4]) - np.array([0.1, -0.3, 0.2])   # from the light to the hand
    expected = harp_scene.CAPTURE_TO_WORLD[:3, :3] @ (towards / np.linalg.norm(towards))
    assert np.abs(shining - expected).max() < 1e-6


@pytest.mark.parametrize("angular_radius", [None, 0.2])
def test_the_bound_sun_is_as_wide_as_the_fitted_light(angular_radius):
    """A fitted light with a size (formats/light_size.py) binds as a sun of that angular diameter,
    whose shadows Cycles softens as the fit's renderer does (tests/test_blender_soft_shadows.py);
    an avatar from before the size, a point light's: a sun of no width."""
    light = {"ambient": 0.3, "position": [0.1, -0.3, 0.2], "shadows": True}
    if angular_radius is not None:
        light["angular_radius"] = angular_radius
    sun = bound_sun(light, [[0.0, 0.0, 0.4]])
    assert sun.data.angle == pytest.approx(2 * (angular_radius or 0.0), abs=1e-6)
