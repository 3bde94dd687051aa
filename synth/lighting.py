"""Lighting presets and backgrounds (bpy). Positions and directions are in the world frame,
which is the OpenCV camera frame (x right, y down, z forward; see viewpoint.py).

- ambient: uniform environment light only (soft, no hard shadows, no lamps at all);
- sun:     one sun (hard self-shadows) plus a weaker environment;
- three:   key, fill and rim point lights plus a weak environment;
- room:    a window's soft key (an area light) and a room's environment whose colour varies
           with direction: cool daylight from the camera's left, warm lamplight from its right,
           a bright ceiling and a dark floor (what a phone sees indoors).
The background seen by the camera is plain grey or a procedural noise pattern; it does not
light the hand (the environment light has its own colour: uniform but for `room`).
"""
from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from .options import BACKGROUNDS, LIGHTING as PRESETS

PLAIN_BACKGROUND = (0.18, 0.18, 0.18)  # linear RGB


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def setup_lighting(scene, preset, background, target, seed=0, collection=None):
    """Create the world and the lights of `preset` around `target` (3,) (the hand's pivot in
    the camera frame, metres). Returns the light description saved in gt.npz."""
    if preset not in PRESETS:
        raise ValueError(f"unknown lighting preset {preset!r}; choose one of {PRESETS}")
    collection = collection or scene.collection
    rng = np.random.default_rng([seed, 5])
    ambient = {"ambient": 1.0, "sun": 0.25, "three": 0.2, "room": 0.45}[preset]
    lights = []
    if preset == "sun":
        lights.append(_sun(collection, _unit([-0.5, -0.7, -0.5]), strength=2.5, angle_deg=0.5))
    elif preset == "three":
        target = np.asarray(target, dtype=np.float64)
        lights.append(_point(collection, "key", target + 0.8 * _unit([-0.6, -0.5, -0.6]), 12.0, 0.1))
        lights.append(_point(collection, "fill", target + 0.9 * _unit([0.8, 0.1, -0.6]), 5.0, 0.2))
        lights.append(_point(collection, "rim", target + 0.8 * _unit([0.3, -0.6, 0.75]), 15.0, 0.1))
    elif preset == "room":
        lights.append(_area(collection, "window", target, _unit([0.7, -0.35, -0.6]), distance=1.0, power=8.0,
                            size=0.6))
    backdrop, environment = _world(scene, ambient, background, rng, room=preset == "room")
    return {"preset": preset, "ambient": environment, "lights": lights, "background": backdrop,
            "frame": "camera (OpenCV)"}


def _orient_light(towards_light):
    """Point the light's -Z (its emission direction) opposite to `towards_light`."""
    z = _unit(towards_light)
    x = _unit(np.cross([0.0, 1.0, 0.0], z)) if abs(z[1]) < 0.99 else _unit(np.cross([1.0, 0.0, 0.0], z))
    y = np.cross(z, x)
    matrix = np.eye(4)
    matrix[:3, :3] = np.stack([x, y, z], axis=1)
    return matrix


def _sun(collection, towards_light, strength, angle_deg):
    data = bpy.data.lights.new("sun", "SUN")
    data.energy = strength
    data.angle = np.radians(angle_deg)
    obj = bpy.data.objects.new("sun", data)
    obj.matrix_world = Matrix(_orient_light(towards_light).tolist())
    collection.objects.link(obj)
    return {"type": "sun", "direction_to_light": towards_light.tolist(), "irradiance_w_m2": strength,
            "angle_deg": angle_deg, "casts_shadows": True}


def _point(collection, name, position, power, radius):
    data = bpy.data.lights.new(name, "POINT")
    data.energy = power
    data.shadow_soft_size = radius
    obj = bpy.data.objects.new(name, data)
    matrix = np.eye(4)
    matrix[:3, 3] = position
    obj.matrix_world = Matrix(matrix.tolist())
    collection.objects.link(obj)
    return {"type": "point", "name": name, "position": np.asarray(position).tolist(), "power_w": power,
            "radius_m": radius, "casts_shadows": True}


def _area(collection, name, target, towards_light, distance, power, size):
    """A square area light of side `size` metres, `distance` metres from `target` along
    `towards_light`, facing the target (it emits along its -Z)."""
    data = bpy.data.lights.new(name, "AREA")
    data.energy = power
    data.size = size
    obj = bpy.data.objects.new(name, data)
    position = np.asarray(target, dtype=np.float64) + distance * towards_light
    matrix = _orient_light(towards_light)
    matrix[:3, 3] = position
    obj.matrix_world = Matrix(matrix.tolist())
    collection.objects.link(obj)
    return {"type": "area", "name": name, "position": np.asarray(position).tolist(), "power_w": power,
            "size_m": size, "casts_shadows": True}


# The room's environment: its colour seen along a world direction d (unit) is
# strength * side(d.x) * height(d.y), each a linear ramp between its two ends (x right, y down).
ROOM_SIDES = ((0.45, 0.62, 1.0), (1.0, 0.75, 0.5))        # towards -x (daylight), +x (lamplight)
ROOM_HEIGHTS = (1.0, 0.3)                                  # towards -y (ceiling), +y (floor)


def _room_light(nodes, links, light):
    """Feed the environment light's colour from the room's two ramps over the ray direction."""
    coordinates = nodes.new("ShaderNodeTexCoord")
    split = nodes.new("ShaderNodeSeparateXYZ")
    links.new(coordinates.outputs["Generated"], split.inputs["Vector"])   # a world's: the ray's direction
    ramps = []
    for axis, ends in (("X", ROOM_SIDES), ("Y", tuple((h, h, h) for h in ROOM_HEIGHTS))):
        to_unit = nodes.new("ShaderNodeMapRange")
        to_unit.inputs["From Min"].default_value, to_unit.inputs["From Max"].default_value = -1.0, 1.0
        links.new(split.outputs[axis], to_unit.inputs["Value"])
        ramp = nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.elements[0].color = (*ends[0], 1.0)
        ramp.color_ramp.elements[1].color = (*ends[1], 1.0)
        links.new(to_unit.outputs["Result"], ramp.inputs["Fac"])
        ramps.append(ramp)
    product = nodes.new("ShaderNodeVectorMath")
    product.operation = "MULTIPLY"
    links.new(ramps[0].outputs["Color"], product.inputs[0])
    links.new(ramps[1].outputs["Color"], product.inputs[1])
    links.new(product.outputs["Vector"], light.inputs["Color"])


def _world(scene, ambient, background, rng, room=False):
    """Environment light of strength `ambient` (uniform white, or the room's with `room`); the
    camera sees the backdrop instead. Returns the backdrop's and the environment's descriptions."""
    if background not in BACKGROUNDS:
        raise ValueError(f"unknown background {background!r}; choose one of {BACKGROUNDS}")
    world = bpy.data.worlds.new("world")
    scene.world = world
    nodes, links = world.node_tree.nodes, world.node_tree.links
    output = nodes["World Output"]
    light = nodes["Background"]
    light.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    light.inputs["Strength"].default_value = ambient
    environment = {"colour": [1.0, 1.0, 1.0], "strength": ambient}
    if room:
        _room_light(nodes, links, light)
        environment = {"colour": "room", "strength": ambient, "sides": [list(c) for c in ROOM_SIDES],
                       "heights": list(ROOM_HEIGHTS)}
    seen = nodes.new("ShaderNodeBackground")
    path = nodes.new("ShaderNodeLightPath")
    mix = nodes.new("ShaderNodeMixShader")
    links.new(path.outputs["Is Camera Ray"], mix.inputs["Fac"])
    links.new(light.outputs["Background"], mix.inputs[1])
    links.new(seen.outputs["Background"], mix.inputs[2])
    links.new(mix.outputs["Shader"], output.inputs["Surface"])
    if background == "plain":
        seen.inputs["Color"].default_value = (*PLAIN_BACKGROUND, 1.0)
        return {"kind": "plain", "colour": list(PLAIN_BACKGROUND)}, environment
    colours = rng.uniform(0.02, 0.5, size=(2, 3))
    coordinates = nodes.new("ShaderNodeTexCoord")
    noise = nodes.new("ShaderNodeTexNoise")
    noise.noise_dimensions = "4D"  # the W input exists only in 4D
    noise.inputs["Scale"].default_value = float(rng.uniform(2.0, 6.0))
    noise.inputs["Detail"].default_value = 6.0
    noise.inputs["W"].default_value = float(rng.uniform(0, 100))
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (*colours[0], 1.0)
    ramp.color_ramp.elements[1].color = (*colours[1], 1.0)
    links.new(coordinates.outputs["Window"], noise.inputs["Vector"])
    links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], seen.inputs["Color"])
    return {"kind": "procedural", "colours": colours.tolist()}, environment
