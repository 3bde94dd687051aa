"""The light's size against Cycles: the penumbra our renderer draws for a light of angular radius
a (render/area_light.py) is the one Cycles draws for the sun the bind makes of it (angle 2 a,
harp_addon/scene.py), on a straight edge 5 cm above a white floor, lit from 45 degrees."""
import math

import numpy as np
import pytest
import torch

bpy = pytest.importorskip("bpy")

from cycles_sphere import render_direct_light  # noqa: E402
from edge_scene import edge_scene  # noqa: E402
from harp_addon import scene as harp_scene  # noqa: E402
from pipeline.formats import light_size  # noqa: E402
from pipeline.render.renderer import Appearance, Light, render  # noqa: E402

pytestmark = pytest.mark.blender
HEIGHT = 0.05                 # the occluder above the floor (m)
SLANT = math.pi / 4           # the light's direction from the floor's normal, from the -x side
RADIUS = 0.15                 # the light's angular radius (radians)
PIXELS = 128                  # Cycles' view: x from -0.1 to 0.1 m


def _quad(name, corners, material):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(c) for c in corners], [], [(0, 1, 2, 3)])
    obj = bpy.data.objects.new(name, mesh)
    obj.data.materials.append(material)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def cycles_profile(tmp_path):
    """(x (PIXELS,), the floor's radiance over its lit radiance along x, rows averaged): Blender
    world, z up, the floor at z = 0, the occluder over x < 0 at z = HEIGHT, seen from above."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    world = bpy.data.worlds.new("black")
    tree = harp_scene._node_tree(world)
    next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBackground").inputs["Strength"].default_value = 0.0
    scene.world = world
    material = bpy.data.materials.new("white")
    tree = harp_scene._node_tree(material)
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    output = next(node for node in tree.nodes if node.bl_idname == "ShaderNodeOutputMaterial")
    tree.links.new(diffuse.outputs["BSDF"], output.inputs["Surface"])
    _quad("floor", [(-0.1, -0.1, 0), (0.1, -0.1, 0), (0.1, 0.1, 0), (-0.1, 0.1, 0)], material)
    _quad("occluder", [(-0.1, -0.1, HEIGHT), (0.0, -0.1, HEIGHT), (0.0, 0.1, HEIGHT), (-0.1, 0.1, HEIGHT)], material)
    data = bpy.data.lights.new("sun", "SUN")
    data.energy, data.angle = math.pi, light_size.sun_angle({"angular_radius": RADIUS})
    sun = bpy.data.objects.new("sun", data)
    sun.rotation_euler = (0.0, -SLANT, 0.0)       # its -Z towards the floor, tilted to come from -x
    scene.collection.objects.link(sun)
    camera_data = bpy.data.cameras.new("camera")
    camera_data.type, camera_data.ortho_scale = "ORTHO", 0.2
    camera = bpy.data.objects.new("camera", camera_data)
    camera.location = (0.0, 0.0, 1.0)
    scene.collection.objects.link(camera)
    scene.camera = camera
    pixels = render_direct_light(PIXELS, 256, tmp_path / "edge.exr")[..., 0]
    x = ((np.arange(PIXELS) + 0.5) / PIXELS - 0.5) * 0.2
    rows = slice(PIXELS // 4, 3 * PIXELS // 4)
    return x, pixels[rows].mean(0) / math.cos(SLANT)


def renderer_profile():
    """The same scene in the camera frame (OpenCV: z away from the camera, the floor at z = 0.5):
    (x of the floor's points along the middle row, their light visibility)."""
    points, mesh = edge_scene(HEIGHT)
    target = torch.tensor([0.0, 0.0, 0.475], dtype=torch.float64)
    position = target + torch.tensor([-math.sin(SLANT), 0.0, -math.cos(SLANT)], dtype=torch.float64)
    light = Light(position, torch.tensor(0.0, dtype=torch.float64), shadows=True, shadow_resolution=512,
                  shadow_target=target, shadow_radius=0.15, angular_radius=RADIUS, samples=64)
    K = torch.tensor([[500.0, 0, 128], [0, 500.0, 128], [0, 0, 1]], dtype=torch.float64)
    images = render(points, mesh, K, 256, 256, outputs=("rgb", "position", "light_visibility"),
                    appearance=Appearance(torch.ones(3, 4, 4, dtype=torch.float64)), light=light, antialiased=False)
    row = images["position"][0, 128]
    floor = (row[:, 2] - 0.5).abs() < 1e-9
    return row[floor, 0].numpy(), images["light_visibility"][0, 128, floor, 0].numpy()


def _crossings(x, profile):
    """x where the profile rises through 0.1, 0.5 and 0.9 (linear between samples)."""
    return [float(np.interp(level, np.maximum.accumulate(profile), x)) for level in (0.1, 0.5, 0.9)]


def test_the_penumbra_is_the_one_cycles_draws_for_the_bound_sun(tmp_path):
    x_cycles, cycles = cycles_profile(tmp_path)
    x_ours, ours = renderer_profile()
    on_floor = x_cycles > 0.002
    low, middle, high = _crossings(x_cycles[on_floor], cycles[on_floor])
    low_ours, middle_ours, high_ours = _crossings(x_ours, ours / ours.max())
    width, width_ours = high - low, high_ours - low_ours
    assert width > 0.018                                       # a wide penumbra: 2 cm from 10% to 90%
    assert abs(width_ours - width) < 0.1 * width, (width_ours, width)
    # Cycles' sun is infinitely far: the penumbra's middle where the edge hides half the disc, HEIGHT tan(SLANT)
    # (to its pixel, 1.6 mm); our shadow camera stands 1.5 m off, which moves it by about 1.2 mm at 5 cm from the
    # hand's centre (tests/test_area_light.py follows it exactly)
    assert abs(middle - HEIGHT * math.tan(SLANT)) < 0.0016, middle
    assert abs(middle_ours - middle) < 0.003, (middle_ours, middle)
