"""The fitted specular lobe in Blender (Cycles as the reference): a Principled BSDF given the
fit's lobe by the bind (harp_addon/scene.py set_specular_lobe), black so that only its sheen
shows, under a sun of strength pi (the fit's light at ambient 0), reflects what the fit's formula
says (render/shading.py specular_shading; formats/specular_lobe.py) at each normal of a sphere;
and under the bind's world alone (no sun), its sheen of the room is the fit's room_specular."""
import numpy as np
import pytest
import torch

bpy = pytest.importorskip("bpy")

from mathutils import Vector  # noqa: E402

from cycles_sphere import render_sphere, sphere_normals  # noqa: E402
from harp_addon import scene as harp_scene  # noqa: E402
from pipeline.formats import specular_lobe  # noqa: E402
from pipeline.render.shading import room_specular, specular_shading  # noqa: E402

pytestmark = pytest.mark.blender
SIZE = 32
TO_LIGHT = np.array([0.35, -0.5, 0.3])     # world: x right, z up, the camera at -y


def sphere_sheen(light, to_light, tmp_path):
    """(H, W, 3) linear radiance of a black, glossy unit sphere (the bind's Principled settings
    for avatar.json's `light`) under a sun of strength pi shining from `to_light` (world), no
    world (cycles_sphere.py)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    material = bpy.data.materials.new("glossy")
    shader = harp_scene._node_tree(material).nodes["Principled BSDF"]
    shader.inputs["Base Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    harp_scene.set_specular_lobe(shader, light)
    sun_data = bpy.data.lights.new("sun", "SUN")
    sun_data.energy, sun_data.angle = float(np.pi), 0.0
    sun = bpy.data.objects.new("sun", sun_data)
    bpy.context.scene.collection.objects.link(sun)
    sun.rotation_mode = "QUATERNION"            # a sun shines along its local -Z: +Z towards the light
    sun.rotation_quaternion = Vector((0.0, 0.0, 1.0)).rotation_difference(Vector(to_light / np.linalg.norm(to_light)))
    return render_sphere(material, SIZE, 64, tmp_path)


def fit_sheen(normals, to_light, roughness, level):
    """(N,) the fit's specular share at world normals (N, 3) for a light from `to_light`, the
    camera along +y (world); the frame does not matter to the formula."""
    n = torch.as_tensor(normals)
    l = torch.as_tensor(to_light / np.linalg.norm(to_light)).expand_as(n)
    v = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64).expand_as(n)
    return specular_shading(n, l, v, torch.tensor(roughness, dtype=torch.float64),
                            torch.tensor(level, dtype=torch.float64))[:, 0].numpy()


@pytest.mark.parametrize("roughness, level", [(0.45, 0.5), (0.7, 0.9)])
def test_the_bound_skin_shines_as_the_fit_does(tmp_path, roughness, level):
    light = {specular_lobe.KEY: specular_lobe.to_description(roughness, level)}
    pixels = sphere_sheen(light, TO_LIGHT, tmp_path).mean(-1)
    inside, normals = sphere_normals(SIZE, 0.9)
    expected = fit_sheen(normals, TO_LIGHT, roughness, level)
    error = np.abs(pixels[inside] - expected)
    peak = expected.max()
    assert peak > 0.05
    # the same highlight: where it is and how bright
    # measured: mean error 0.1-0.2% of the peak, 95th percentile 0.4-0.5%
    assert error.mean() < 0.01 * peak and np.percentile(error, 95) < 0.03 * peak, (error.mean(), peak)
    assert np.unravel_index(np.argmax(np.where(inside, pixels, 0)), inside.shape) == \
        np.unravel_index(np.argmax(np.where(inside, _image(inside, expected), 0)), inside.shape)


def room_sheen(light, make_world, tmp_path):
    """(H, W, 3) linear radiance of the black, glossy unit sphere (the bind's lobe for `light`)
    under the world `make_world()` makes alone."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    material = bpy.data.materials.new("glossy")
    shader = harp_scene._node_tree(material).nodes["Principled BSDF"]
    shader.inputs["Base Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    harp_scene.set_specular_lobe(shader, light)
    bpy.context.scene.world = make_world()
    return render_sphere(material, SIZE, 256, tmp_path)


@pytest.mark.parametrize("roughness, level", [(0.35, 0.5), (0.7, 0.9)])
def test_the_bound_skin_reflects_the_room_as_the_fit_does(tmp_path, roughness, level):
    """A uniform room of radiance 0.6 (the bind's world for ambient 0.6): the sheen at each
    normal is the lobe's tabulated reflectance of uniform light (room_sheen_table) times 0.6."""
    light = {specular_lobe.KEY: specular_lobe.to_description(roughness, level)}
    pixels = room_sheen(light, lambda: harp_scene._fitted_world("room", 0.6, None), tmp_path).mean(-1)
    inside, normals = sphere_normals(SIZE, 0.9)
    n = torch.as_tensor(normals)
    v = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64).expand_as(n)
    expected = room_specular(n, v, torch.tensor(roughness, dtype=torch.float64), torch.tensor(level, dtype=torch.float64),
                             0.6)[:, 0].numpy()
    error = np.abs(pixels[inside] - expected)
    assert expected.min() > 0.005
    assert error.mean() < 0.03 * expected.mean() and np.percentile(error, 95) < 0.08 * expected.mean(), \
        (error.mean(), np.percentile(error, 95), expected.mean())


def _image(inside, values):
    image = np.zeros(inside.shape)
    image[inside] = values
    return image


def test_a_fit_without_a_sheen_binds_matte_and_an_old_folder_satin():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    shader = harp_scene._node_tree(bpy.data.materials.new("skin")).nodes["Principled BSDF"]
    harp_scene.set_specular_lobe(shader, {specular_lobe.KEY: None})
    assert shader.inputs["Specular IOR Level"].default_value == 0.0
    harp_scene.set_specular_lobe(shader, {"ambient": 0.6})
    assert shader.inputs["Specular IOR Level"].default_value == pytest.approx(0.5)
    assert shader.inputs["Roughness"].default_value == pytest.approx(0.5)
    harp_scene.set_specular_lobe(shader, {specular_lobe.KEY: {"roughness": 0.35, "level": 0.3}})
    assert shader.inputs["Roughness"].default_value == pytest.approx(0.35)
    assert shader.inputs["Specular IOR Level"].default_value == pytest.approx(0.3)
