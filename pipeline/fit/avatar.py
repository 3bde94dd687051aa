"""The avatar being fitted: every optimised parameter and the posed, displaced mesh it makes.

    V = LBS_subdivided(T(shape) + d * n_rest, pose)   (one scalar per subdivided vertex, along
                                                       the normal of the shaped rest surface)

d is the mean of two values of the unsubdivided mesh per subdivided point (its parents:
`displacement_parents`, FitSettings.displacement_grid "coarse"), or its own value ("fine").

The reference implementation displaces along the *posed* normals after skinning (method_facts);
we displace the rest surface and then skin it, so that the fitted surface is exactly what a
linear-blend-skinning rig (Blender's Armature modifier, a game engine) animates: the avatar
folder's rest mesh posed by the armature reproduces every fitted frame. It is also cheaper:
the normals are taken once per step, not once per frame.
Per frame: global rotation, translation, joint rotations (the wrist's only in hand+forearm
mode), and the camera's exposure (a colour gain; fitted only when the clip needs it). Shared:
shape, displacements, albedo texture, normal map, light position, ambient ratio, and the
environment light (spherical harmonics, formats/environment_light.py; in use only while the
`environment_on` switch is set), and the skin's specular lobe (roughness and level,
formats/specular_lobe.py; in use only while `specular_on` is set).
"""
from __future__ import annotations

import time

import numpy as np
import torch

from ..formats import environment_light
from ..formats.colour_model import LINEAR, checked
from ..formats.specular_lobe import LEVEL_MAX, ROUGHNESS_RANGE
from ..handmodel.lbs import HandModel
from ..render.occlusion import bounce_radiance, hand_lost_light
from ..render.renderer import Appearance, Light, RenderMesh
from ..render.fused import vertex_normals
from ..render.vector_ops import normalized

SKIN_RGB = (232 / 255, 190 / 255, 172 / 255)
INITIAL_AMBIENT = 0.6
INITIAL_ROUGHNESS = 0.5      # a satin skin
INITIAL_SPECULAR_LEVEL = 0.2   # a faint sheen (F0 0.016); clips without one bring it to about 0.09 (bench_specular.py)
# the avatar's parameters by kind
POSE = ("global_orient", "transl", "pose")
PER_FRAME = POSE + ("exposure",)
SHAPE = ("betas", "displacement")
TEXTURES = ("albedo", "normal_map")
LIGHT = ("light_position", "ambient_logit", "environment")
MATERIAL = ("roughness_logit", "specular_logit")   # the skin's specular lobe
APPEARANCE = TEXTURES + LIGHT + MATERIAL
# buffers that say which parts of the light and material are in use, and the light's size (saved with the avatar)
SWITCHES = ("environment_on", "specular_on", "light_angle")
# the points a light with a size is shaded over in the fit's solves and scores (render/area_light.py; each costs
# a shadow map): 16 keep a straight shadow edge's penumbra within 0.07 of the analytic one, 64 within 0.02
# (tests/test_area_light.py); the albedo solves of a 24-frame clip took 21 s with 8, 31 s with 16, 13 s with a
# point light (docs/fidelity.md, "The light's size")
AREA_SAMPLES = 8
# a frame's room-light occlusion is measured again once its hand or a joint has turned by this much (radians)
# or the shape has changed by this much (standard deviations) since it was last measured
OCCLUSION_POSE_TOLERANCE = 0.1
OCCLUSION_SHAPE_TOLERANCE = 0.5


class Avatar(torch.nn.Module):
    """Parameters of one fit. `model` is the subdivided HandModel of the clip's mode and side."""

    def __init__(self, model: HandModel, initial, frames, texture_size=512, light_position=None, coarse_model=None,
                 displacement_parents=None, colour_model=LINEAR):
        super().__init__()
        self.model = model
        # how the albedo and light make the frames' values (formats/colour_model.py; FitSettings.colour_model)
        self.linear_light = checked(colour_model) == LINEAR
        self.coarse_model = coarse_model   # the unsubdivided model, for the alignment stage
        dtype, device = model.v_template.dtype, model.v_template.device
        # displacements on the unsubdivided mesh, carried to the subdivided one as the mean of each
        # point's two parents (subdivision.midpoint_parents), or None: one per subdivided point
        self.register_buffer("displacement_parents", None if displacement_parents is None else
                             torch.as_tensor(displacement_parents, device=device), persistent=False)

        def parameter(array):
            return torch.nn.Parameter(torch.as_tensor(np.array(array), dtype=dtype, device=device))

        self.global_orient = parameter(initial.global_orient[frames])
        self.exposure = parameter(np.zeros((len(frames), 3)))   # log colour gain of each frame's camera
        self.transl = parameter(initial.transl[frames])
        self.pose = parameter(initial.pose[frames])
        self.betas = parameter(initial.betas)
        count = model.data.num_vertices if displacement_parents is None else int(np.max(displacement_parents)) + 1
        self.displacement = parameter(np.zeros(count))
        self.albedo = parameter(np.broadcast_to(np.array(SKIN_RGB)[:, None, None], (3, texture_size, texture_size)))
        flat = np.zeros((3, texture_size, texture_size))
        flat[2] = 1.0
        self.normal_map = parameter(flat)
        if light_position is None:  # in front of the hand, above the camera
            light_position = np.asarray(initial.transl[frames]).mean(0) * np.array([1.0, 1.0, 0.5]) + [0.0, -0.3, 0.0]
        self.light_position = parameter(light_position)
        self.ambient_logit = parameter(np.log(INITIAL_AMBIENT / (1 - INITIAL_AMBIENT)))
        self.environment = parameter(np.zeros((environment_light.COEFFICIENTS, 3)))
        self.register_buffer("environment_on", torch.zeros((), dtype=torch.bool, device=device))
        for name, value in initial_material().items():
            setattr(self, name, parameter(value))
        self.register_buffer("specular_on", torch.zeros((), dtype=torch.bool, device=device))
        # the light's angular radius (radians; formats/light_size.py), decided after the stages (fit/light_size.py)
        self.register_buffer("light_angle", torch.zeros((), dtype=dtype, device=device))
        self.area_samples = AREA_SAMPLES
        # the wrist joint rotates the hand against the forearm: free only with a forearm
        self.register_buffer("pose_mask", torch.ones(16, 3, dtype=dtype, device=device))
        if model.mode == "hand":
            self.pose_mask[0] = 0
        self.register_buffer("frame_numbers", torch.as_tensor(np.asarray(frames), device=device), persistent=False)
        # the room light's occlusion (FitSettings.occlusion, set by problem.build_problem): per frame, measured at
        # a pose and kept (not saved)
        self.occlusion = False
        self.light_falloff = False   # the point light's inverse-square falloff (FitSettings.light_falloff)
        self._hand_centre = None     # hand_centre's, kept
        self._lost, self._lost_pose, self._lost_betas = None, None, None
        # what measuring it has cost in this process (report.json's occlusion): frames measured, seconds (on CUDA
        # the seconds to queue the work)
        self.occlusion_measurements, self.occlusion_seconds = 0, 0.0
        self.mesh = RenderMesh.from_model_data(model.data, device=device, dtype=dtype)
        if coarse_model is not None:
            self.coarse_mesh = RenderMesh.from_model_data(coarse_model.data, device=device, dtype=dtype)

    def parameter_group(self, names):
        return [getattr(self, name) for name in names]

    @property
    def ambient(self):
        return torch.sigmoid(self.ambient_logit)

    @property
    def roughness(self):
        low, high = ROUGHNESS_RANGE
        return low + (high - low) * torch.sigmoid(self.roughness_logit)

    @property
    def specular_level(self):
        return LEVEL_MAX * torch.sigmoid(self.specular_logit)

    def specular(self):
        """(roughness, level) of the skin's specular lobe, or None while it is switched off."""
        return (self.roughness, self.specular_level) if bool(self.specular_on) else None

    def unit_normal_map(self):
        """(3, T, T) the normal map's texels made unit length (vector_ops.normalized over texels last:
        eight times as fast as F.normalize over the first dimension, 15 ms a call at 256 texels)."""
        return normalized(self.normal_map.permute(1, 2, 0)).permute(2, 0, 1)

    @torch.no_grad()
    def resize_textures(self, size):
        """The albedo and the normal map resampled (bilinear) to `size` x `size` texels, as new
        parameters in their place: the finer albedo solve fills a texture as fine as its frames hold
        (fitting._after_the_stages, texel_footprint.py), and a resumed fit's avatar takes the size
        its checkpoint was saved at."""
        for name in ("albedo", "normal_map"):
            old = getattr(self, name)
            if old.shape[-1] == size:
                continue
            new = torch.nn.functional.interpolate(old.detach()[None], size=(size, size), mode="bilinear",
                                                  align_corners=False)[0]
            setattr(self, name, torch.nn.Parameter(new, requires_grad=old.requires_grad))

    def appearance(self, normal_map=True):
        return Appearance(self.albedo.clamp(0, 1), self.unit_normal_map() if normal_map else None)

    def exposure_gain(self, batch):
        """(B, 1, 1, 3) colour gain of the frames `batch`: what the camera's exposure and white
        balance did to them."""
        return torch.exp(self.exposure[batch])[:, None, None, :]

    def light(self, shadows=False, batch=None, vertices=None, samples=None):
        """The light of the frames `batch` posed as `vertices` (B, V, 3) (the subdivided mesh), with
        their room-light occlusion when it is on; without them, a light with none. A light with a
        size (`light_angle`) is shaded over `samples` points of it (default `area_samples`); the
        gradient steps ask for 1, its centre (a point light: each point costs a shadow map)."""
        occlusion = None if batch is None or not self.occlusion else self.room_occlusion(batch, vertices)
        return Light(self.light_position, self.ambient, shadows=shadows,
                     environment=self.environment if bool(self.environment_on) else None, specular=self.specular(),
                     linear=self.linear_light, occlusion=occlusion,
                     bounce=None if occlusion is None else bounce_radiance(self.albedo, self.ambient, self.linear_light),
                     angular_radius=float(self.light_angle),
                     samples=self.area_samples if samples is None else samples, falloff=self.falloff_reach())

    @torch.no_grad()
    def falloff_reach(self) -> float:
        """Where the light's falloff is 1 (renderer.Light.falloff): its distance from the hand's mean
        place over the clip's frames (its keypoints' mean, hand_centre), one distance for every
        frame, so that the light's strength is what it gives the hand there; 0 while it is off."""
        if not self.light_falloff:
            return 0.0
        return float((self.light_position - self.hand_centre()).norm())

    @torch.no_grad()
    def hand_centre(self, refresh=False):
        """(3,) the mean of the hand's 21 keypoints over every frame, posed as they stand when first
        asked (or with `refresh`): the root translation can lie down a forearm, centimetres off it."""
        if refresh or self._hand_centre is None:
            frames = torch.arange(len(self.global_orient), device=self.pose.device)
            self._hand_centre = torch.cat([self.posed(batch)[1][:, :21].reshape(-1, 3)
                                           for batch in frames.split(32)]).mean(0)
        return self._hand_centre

    @torch.no_grad()
    def measure_occlusion(self, batch_size=8, exact=False, when_off=False):
        """Measure the room light's occlusion of every frame whose pose has moved past the
        tolerance since it was last measured (room_occlusion), or of every frame at its pose now
        (`exact`: what the outputs are made with, so that a resumed fit makes the same ones);
        nothing while it is off, unless `when_off` (the albedo solve's openness reads it)."""
        if exact and self.light_falloff:
            self.hand_centre(refresh=True)      # the falloff's reach from the poses the outputs are made with
        if not (self.occlusion or when_off):
            return
        if exact and self._lost_pose is not None:
            self._lost_pose.fill_(float("inf"))
        for batch in torch.arange(len(self.global_orient), device=self.pose.device).split(batch_size):
            self.room_occlusion(batch, self.posed(batch)[0])

    def occlusion_state(self):
        """What room_occlusion holds (to put back with restore_occlusion_state): a calibration's
        throwaway steps must leave the fit as they found it."""
        return tuple(None if value is None else value.clone() for value in (self._lost, self._lost_pose, self._lost_betas))

    def restore_occlusion_state(self, state):
        self._lost, self._lost_pose, self._lost_betas = state

    @torch.no_grad()
    def room_occlusion(self, batch, vertices):
        """(B, V, 9) the room light each vertex of the frames `batch`, posed as `vertices`, does not
        get for the hand in the way (render/occlusion.py). Measured once per frame and kept until
        its pose or the shape moves by OCCLUSION_POSE_TOLERANCE or OCCLUSION_SHAPE_TOLERANCE (the
        visibility has no gradient: a fixed factor of the pose it was measured at)."""
        batch = torch.as_tensor(batch, dtype=torch.long, device=vertices.device).reshape(-1)
        pose = torch.cat([self.global_orient[batch], (self.pose[batch] * self.pose_mask).flatten(1)], dim=1)
        if self._lost is None or self._lost.shape[1] != vertices.shape[1] or self._lost.device != vertices.device:
            frames = len(self.global_orient)
            self._lost = vertices.new_zeros(frames, vertices.shape[1], 9)
            self._lost_pose = torch.full((frames, pose.shape[1]), float("inf"), dtype=pose.dtype, device=pose.device)
            self._lost_betas = self.betas.detach().clone()
        if (self.betas - self._lost_betas).abs().max() > OCCLUSION_SHAPE_TOLERANCE:
            self._lost_pose.fill_(float("inf"))
            self._lost_betas = self.betas.detach().clone()
        stale = (pose - self._lost_pose[batch]).abs().amax(1) > OCCLUSION_POSE_TOLERANCE
        if stale.any():
            start = time.perf_counter()
            self._lost[batch[stale]] = hand_lost_light(vertices[stale].detach(), self.model.data,
                                                       self.mesh.faces).to(self._lost.dtype)
            self._lost_pose[batch[stale]] = pose[stale]
            self.occlusion_measurements += int(stale.sum())
            self.occlusion_seconds += time.perf_counter() - start
        return self._lost[batch]

    @torch.no_grad()
    def switch_environment(self, on: bool):
        """Use the environment light or not; switched off, its coefficients are 0 and stay out
        of every render (they get no gradient, so the optimiser leaves them)."""
        self.environment_on.fill_(bool(on))
        if not on:
            self.environment.zero_()

    @torch.no_grad()
    def switch_specular(self, on: bool):
        """Use the specular lobe or not; switched off, it stays out of every render (its two
        parameters get no gradient, so the optimiser leaves them)."""
        self.specular_on.fill_(bool(on))

    def posed(self, batch):
        """(vertices (B, V, 3), keypoints (B, K, 3)) of the frames `batch` (indices into the fit's
        frames): the displaced rest surface, skinned."""
        pose = self.pose[batch] * self.pose_mask
        out = self.model(self.betas, pose, self.global_orient[batch], self.transl[batch],
                         rest_vertices=self.displaced_rest())
        return out.vertices, out.keypoints

    def displacement_field(self):
        """(V,) the displacement of every subdivided point along its rest normal (metres)."""
        if self.displacement_parents is None:
            return self.displacement
        parents = self.displacement_parents
        return 0.5 * (self.displacement.index_select(0, parents[:, 0]) + self.displacement.index_select(0, parents[:, 1]))

    def displaced_rest(self):
        """(V, 3) the personal rest surface: the shaped template displaced along its normals."""
        vertices, _, _ = self.model.shaped(self.betas)
        normals = vertex_normals(vertices[None], self.mesh.faces)[0]
        return vertices + self.displacement_field()[:, None] * normals

    def posed_coarse(self, batch):
        """(vertices, keypoints) of the unsubdivided model without displacements: the alignment's
        cheap stand-in for `posed` (a quarter of the vertices)."""
        out = self.coarse_model(self.betas, self.pose[batch] * self.pose_mask, self.global_orient[batch],
                                self.transl[batch])
        return out.vertices, out.keypoints

    def rest_mesh(self):
        """Personalised rest vertices (V, 3), detached: what the avatar folder's rig holds."""
        with torch.no_grad():
            return self.displaced_rest()


def initial_material() -> dict:
    """{MATERIAL parameter: value} where the specular lobe starts: INITIAL_ROUGHNESS and
    INITIAL_SPECULAR_LEVEL through the sigmoids of Avatar.roughness and Avatar.specular_level."""
    low, high = ROUGHNESS_RANGE
    return {"roughness_logit": _logit((INITIAL_ROUGHNESS - low) / (high - low)),
            "specular_logit": _logit(INITIAL_SPECULAR_LEVEL / LEVEL_MAX)}


def _logit(p):
    return float(np.log(p / (1 - p)))
