"""The renderer: the primitives composed into the images a fit asks for, and nothing more.

    images = render(points, mesh, camera_K, 256, 256, outputs=("alpha",))
    images = render(points, mesh, K, 256, 256, outputs=("rgb", "alpha"), appearance=..., light=...)

Requested outputs decide the work: a silhouette-only call does no texture or shading work,
and shadows cost nothing when off. Colour images are composited over the background before
the silhouette antialiasing, so edges blend into the background like real photographs.
"""
from __future__ import annotations

import dataclasses

import torch

from ..formats.colour_model import linear_to_srgb, srgb_to_linear
from . import area_light
from . import fused as fused_ops
from . import interpolate as reference_interpolate
from . import occlusion as room_occlusion
from . import rasterize as reference_rasterize
from . import shading as reference_shading
from . import shadow_map as reference_shadow_map
from .antialias import EdgeTopology, edge_topology
from .antialias import antialias as reference_antialias
from .interpolate import to_image
from .texture import sample_texture
from .vector_ops import normalized

OUTPUTS = ("alpha", "rgb", "depth", "normal", "albedo", "uv", "shading_normal", "lost_light", "position",
           "light_visibility", "vertex_values")
# the outputs that come from the shading of the rgb output, and with it only
SHADING_OUTPUTS = ("shading_normal", "lost_light", "position", "light_visibility")


@dataclasses.dataclass(frozen=True)
class Primitives:
    """The steps whose work the fused path lays out differently (fused.py); same formulas."""

    rasterize: object
    fragments: object
    interpolate_many: object
    vertex_normals: object
    uv_tangents: object
    perturbed_normal: object
    shadow_visibility: object
    lit_colour: object
    composite: object
    antialias: object


REFERENCE = Primitives(
    reference_rasterize.rasterize, reference_interpolate.fragments,
    lambda attributes, frags, faces: [reference_interpolate.interpolate(a, frags, faces) for a in attributes],
    reference_shading.vertex_normals, reference_shading.uv_tangents, reference_shading.perturbed_normal,
    lambda points, faces, position, frags, *light: reference_shadow_map.shadow_visibility(
        points, faces, position, frags.frame, *light), reference_shading.lit_colour,
    lambda values, behind, frags: [torch.where(_covered(frags), to_image(v, frags), b) for v, b in zip(values, behind)],
    lambda images, *geometry: [reference_antialias(image, *geometry) for image in images])
FUSED = Primitives(fused_ops.rasterize, fused_ops.fragments, fused_ops.interpolate_many,
                   fused_ops.vertex_normals, fused_ops.uv_tangents, fused_ops.perturbed_normal,
                   fused_ops.shadow_visibility, fused_ops.lit_colour, fused_ops.composite,
                   fused_ops.antialias)


@dataclasses.dataclass
class RenderMesh:
    """Topology of a mesh for rendering (positions come per call)."""

    faces: torch.Tensor                 # (F, 3) long
    uvs: torch.Tensor | None = None     # (U, 2) in [0, 1], v up
    faces_uv: torch.Tensor | None = None  # (F, 3) long
    topology: EdgeTopology | None = None

    @classmethod
    def from_model_data(cls, data, device=None, dtype=torch.float32):
        faces = torch.as_tensor(data.faces, dtype=torch.long, device=device)
        return cls(faces, torch.as_tensor(data.uvs, dtype=dtype, device=device),
                   torch.as_tensor(data.faces_uv, dtype=torch.long, device=device), edge_topology(faces))

    def edges(self):
        if self.topology is None:
            self.topology = edge_topology(self.faces)
        return self.topology


@dataclasses.dataclass
class Appearance:
    albedo: torch.Tensor                   # (3, H, W) in [0, 1]
    normal_map: torch.Tensor | None = None  # (3, H, W) tangent-space vectors in [-1, 1]


@dataclasses.dataclass
class Light:
    position: torch.Tensor      # (3,) point light in the camera frame, metres
    ambient: torch.Tensor       # scalar ambient ratio a in (0, 1)
    shadows: bool = False
    shadow_resolution: int = 256
    shadow_target: torch.Tensor | None = None   # (3,) what the shadow camera looks at (default: mesh centre)
    shadow_radius: float | None = None          # radius the shadow map covers (default: the mesh's)
    # (8, 3) the environment light's spherical harmonics (formats/environment_light.py); None: none
    environment: torch.Tensor | None = None
    # (roughness, level) of the skin's specular lobe (scalar tensors; formats/specular_lobe.py); None: none
    specular: tuple | None = None
    # shade in linear light (formats/colour_model.py "linear"): the albedo decoded from sRGB, the lit colour
    # encoded back; False: the albedo's values shaded as they are ("display")
    linear: bool = False
    # (B, V, 9) per vertex, the room light (ambient and environment) the hand's own surfaces keep
    # from it (render/occlusion.py lost_light); None: every point sees the whole room
    occlusion: torch.Tensor | None = None
    # (3,) the light the skin sends back along a blocked direction (render/occlusion.py bounce_radiance); None: none
    bounce: torch.Tensor | None = None
    # the light's angular radius seen from the hand (radians; render/area_light.py): its diffuse shading and shadows
    # averaged over `samples` points of a disc that size; 0: a point light
    angular_radius: float = 0.0
    samples: int = 16
    # the point light's direct light falls off with the square of the distance (shading.distance_falloff), as a
    # lamp's or a window's does a metre away: 1 at this distance from the light (metres), brighter nearer; 0: a
    # light so far away that it is as strong everywhere on the hand (HARP's model)
    falloff: float = 0.0


def render(points, mesh: RenderMesh, K, height, width, outputs=("alpha",), appearance=None,
           light=None, background=None, antialiased=True, fused=True, vertex_values=None):
    """Render a batch of frames of one mesh.

    points (B, V, 3) vertices in the camera frame (OpenCV axes, metres); K (3, 3) or (B, 3, 3).
    Returns {name: (B, H, W, C)}: alpha (C=1), rgb (3, lit colour over `background`, a (3,)
    tensor or (B, H, W, 3) image, default black), depth (1, +inf where empty), normal (3,
    camera frame), albedo (3, unlit), uv (2, the texture coordinates seen, v up), shading_normal
    (3, the normal the light sees: the normal map's, camera frame; only with rgb), lost_light (9,
    the light's `occlusion` interpolated; only with rgb and an occlusion), position (3, the
    surface point, camera frame; only with rgb), light_visibility (1, the share of the point
    light that reaches the point: its shadow test, 1 without shadows, the mean over its points for
    a light with a size; only with rgb), vertex_values (C, the per-vertex `vertex_values` (B, V, C)
    interpolated over the faces as the surface is). With
    shading_normal, position, light_visibility and lost_light, lobe_colour gives the specular
    lobe's share of rgb at any pixel without a second render. alpha and rgb carry silhouette
    gradients when antialiased. fused=False takes the reference primitives (the same images and
    gradients, slower: fused.py).
    """
    unknown = set(outputs) - set(OUTPUTS)
    if unknown:
        raise ValueError(f"unknown render outputs {sorted(unknown)}; choose from {OUTPUTS}")
    if set(SHADING_OUTPUTS) & set(outputs) and "rgb" not in outputs:
        raise ValueError(f"the {', '.join(SHADING_OUTPUTS)} outputs come with rgb only")
    if "lost_light" in outputs and (light is None or light.occlusion is None):
        raise ValueError("the lost_light output needs a light with an occlusion")
    if "vertex_values" in outputs and vertex_values is None:
        raise ValueError("the vertex_values output needs the vertex_values (B, V, C) to interpolate")
    ops = FUSED if fused else REFERENCE
    faces = mesh.faces
    rast = ops.rasterize(points.detach(), faces, K, height, width)
    frags = ops.fragments(points, faces, K, rast)
    result = {}
    if "depth" in outputs:
        result["depth"] = rast.depth.unsqueeze(-1)
    if "vertex_values" in outputs:
        values, = ops.interpolate_many([vertex_values.to(points.dtype)], frags, faces)
        result["vertex_values"] = to_image(values, frags)
    smooth_normals = position = None
    if "rgb" in outputs:
        smooth_normals, position = ops.interpolate_many([ops.vertex_normals(points, faces), points], frags, faces)
    elif "normal" in outputs:
        smooth_normals, = ops.interpolate_many([ops.vertex_normals(points, faces)], frags, faces)
    if "normal" in outputs:
        result["normal"] = to_image(torch.nn.functional.normalize(smooth_normals, dim=-1), frags)
    uv = tangent = handedness = None
    if {"rgb", "albedo", "uv"} & set(outputs):
        if mesh.uvs is None:
            raise ValueError("rgb/albedo/uv outputs need a mesh with UVs")
        if "rgb" in outputs and appearance is not None and appearance.normal_map is not None:
            tangents, handedness = ops.uv_tangents(points, mesh.faces, mesh.uvs, mesh.faces_uv)
            uv, tangent = ops.interpolate_many([mesh.uvs, tangents], frags, mesh.faces_uv)
        else:
            uv, = ops.interpolate_many([mesh.uvs], frags, mesh.faces_uv)
        if "uv" in outputs:
            result["uv"] = to_image(uv, frags)
    if {"rgb", "albedo"} & set(outputs) and appearance is None:
        raise ValueError("rgb/albedo outputs need an appearance")
    if "rgb" in outputs and light is None:
        raise ValueError("rgb output needs a light")
    if "albedo" in outputs:
        result["albedo"] = to_image(sample_texture(appearance.albedo, uv), frags)
    layers = []
    if "rgb" in outputs:
        # in linear light the texture is decoded before it is filtered, as Blender's image textures are
        albedo = sample_texture(srgb_to_linear(appearance.albedo) if light.linear else appearance.albedo, uv)
        if appearance.normal_map is not None:
            value = sample_texture(appearance.normal_map, uv)
            normal = ops.perturbed_normal(smooth_normals, tangent, handedness[frags.face], value)
        else:
            normal = normalized(smooth_normals)
        lost = None
        if light.occlusion is not None:
            lost, = ops.interpolate_many([light.occlusion.to(points.dtype)], frags, faces)
        colour, visibility = _lit_colour(ops, points, faces, frags, position, albedo, normal, light, lost)
        if "shading_normal" in outputs:
            result["shading_normal"] = to_image(normal, frags)
        if "lost_light" in outputs:
            result["lost_light"] = to_image(lost, frags)
        if "position" in outputs:
            result["position"] = to_image(position, frags)
        if "light_visibility" in outputs:
            seen = torch.ones_like(position[:, :1]) if visibility is None else visibility
            result["light_visibility"] = to_image(seen, frags)
        layers.append(("rgb", colour, _background(background, points, height, width)))
    if "alpha" in outputs:
        ones = torch.ones(len(frags.pixel), 1, dtype=points.dtype, device=points.device)
        layers.append(("alpha", ones, torch.zeros(1, dtype=points.dtype, device=points.device).expand(
            points.shape[0], height, width, 1)))
    if layers:
        images = ops.composite([values for _, values, _ in layers], [behind for _, _, behind in layers], frags)
        if antialiased:
            images = ops.antialias(images, points, K, rast, mesh.edges())
        result.update((name, image) for (name, _, _), image in zip(layers, images))
    return result


def _light_places(light, points):
    """The points the light's diffuse shading is averaged over (area_light.light_points): its
    position alone for a point light; for one with a size, points of a disc facing what the shadow
    camera looks at (`shadow_target`, else each frame's mesh centre)."""
    if light.angular_radius <= 0 or light.samples <= 1:
        return [light.position.to(points.dtype)]
    centre = reference_shadow_map.shadow_target(points, light.shadow_target)
    position = light.position.to(points.dtype)
    position = position.expand(points.shape[0], 3) if position.dim() == 1 else position
    return area_light.light_points(position, centre, light.angular_radius, light.samples)


def falloff_reach(light, points):
    """(B, 1) the distance from the light at which its falloff is 1 (Light.falloff), for each frame of
    `points` (B, V, 3); None without a falloff."""
    if not light.falloff:
        return None
    return points.new_full((points.shape[0], 1), float(light.falloff))


def _light_position(light_position, frame):
    """(N, 3) or (3,): a light position ((3,) or one per frame (B, 3)) for fragments of frames `frame` (N,)."""
    return light_position[frame] if light_position.dim() == 2 else light_position


def _lit_colour(ops, points, faces, frags, position, albedo, normal, light, lost=None):
    """(the colour of each fragment (N, C), the point light's visibility (N, 1) or None without
    shadows): `albedo` (linear already in linear light) lit, the point light (or each point of an
    area light, averaged) seen as its shadow test says, less the room light the hand keeps from it
    (`lost`, (N, 9) interpolated lost_light, or None), encoded to sRGB in linear light. The
    specular highlight is the light's centre's, under the mean visibility (lobe_colour's numbers)."""
    places = _light_places(light, points)
    reach = falloff_reach(light, points)
    colour, visibility = 0.0, None
    for place in places:
        seen = None
        if light.shadows:
            seen = ops.shadow_visibility(points, faces, position, frags, place, light.shadow_resolution,
                                         light.shadow_target, light.shadow_radius)
            visibility = seen if visibility is None else visibility + seen
        here = _light_position(place, frags.frame)
        if reach is not None:     # the falloff multiplies what reaches the point, as the shadow test does
            falloff = reference_shading.distance_falloff(here, position, reach[frags.frame])
            seen = falloff if seen is None else seen * falloff
        colour = colour + ops.lit_colour(albedo, normal, position, here, light.ambient, seen)
    if len(places) > 1:
        colour = colour / len(places)
        visibility = None if visibility is None else visibility / len(places)
    if light.environment is not None:
        colour = colour + albedo * reference_shading.environment_shading(normal, light.environment)
    if lost is not None:
        colour = colour - albedo * room_occlusion.lost_shading(lost, light.ambient, light.environment, light.bounce)
    if light.specular is not None:
        centre = _light_position(light.position.to(position.dtype), frags.frame)
        reaching = visibility
        if reach is not None:
            falloff = reference_shading.distance_falloff(centre, position, reach[frags.frame])
            reaching = falloff if visibility is None else visibility * falloff
        for part in _lobe_parts(normal, position, centre, light, reaching, lost):
            colour = colour + part
    return (linear_to_srgb(colour) if light.linear else colour), visibility


def lobe_colour(normal, position, light, frame, visibility=None, lost=None, reach=None):
    """(N, C) the specular lobe's share of the colour at N surface points (C = 1, or 3 with an
    environment light), in the shading's units (not encoded): its highlight under the point light,
    seen as `visibility` says ((N, 1), None: unshadowed), and its sheen of the room, less the share
    of the room the hand keeps from the point (`lost`, (N, 9), or None). `normal` (N, 3) unit, the
    shading normal, and `position` (N, 3) in the camera frame; `frame` (N,) each point's frame in
    the batch (for a light placed per frame); `light` a Light with a lobe; `reach` (N, 1) each
    point's frame's falloff_reach, for a light with a falloff. The same numbers as the lobe's share
    of render()'s rgb."""
    centre = _light_position(light.position.to(position.dtype), frame)
    if light.falloff:
        if reach is None:
            raise ValueError("a light with a falloff needs each point's reach (falloff_reach)")
        falloff = reference_shading.distance_falloff(centre, position, reach)
        visibility = falloff if visibility is None else visibility * falloff
    highlight, room = _lobe_parts(normal, position, centre, light, visibility, lost)
    return highlight + room


def _lobe_parts(normal, position, light_position, light, visibility=None, lost=None):
    """lobe_colour's two parts: the highlight under the point light, the sheen of the room (added
    to the colour one after the other, so that rgb sums them as it always has)."""
    to_light = normalized(light_position - position)
    to_camera = normalized(-position)   # the camera is the origin
    highlight = reference_shading.specular_shading(normal, to_light, to_camera, *light.specular) * (1 - light.ambient)
    highlight = highlight if visibility is None else highlight * visibility
    # and the room's light in the lobe, less the share of the room the hand keeps from the point
    room = reference_shading.room_specular(normal, to_camera, *light.specular, light.ambient, light.environment)
    return highlight, (room if lost is None else room * (1 - lost[:, :1]).clamp(min=0))


def _covered(frags):
    """(B, H, W, 1) bool: the pixels the fragments cover (the rasterisation's covered pixels)."""
    return to_image(torch.ones(len(frags.pixel), 1, dtype=torch.bool, device=frags.pixel.device), frags, False)


def _background(background, points, height, width):
    """What the colour layer lies over: (B, H, W, 3), a broadcast view where it can be."""
    batch = points.shape[0]
    if background is None:
        background = torch.zeros(3, dtype=points.dtype, device=points.device)
    background = torch.as_tensor(background, dtype=points.dtype, device=points.device)
    if background.dim() == 1:
        return background.view(1, 1, 1, 3).expand(batch, height, width, 3)
    return background.expand(batch, height, width, 3)
