"""The true identity of a synthetic clip rendered by Cycles in new poses: what a user sees of
the real hand, where fidelity.py's part (a) renders the truth with our own renderer.

The clip's own synth settings (sequence.json's metadata: identity, skin, lighting preset,
samples) rebuild its person and scene (synth/clip.py); each new pose is placed and framed as
fidelity.framing() does, with the clip's lights around the hand as in the clip. The avatar is
compared under its fitted light, moved with the hand (fitted_light()), so the figure judges
what a user of the avatar would see next to the real hand under the clip's light.

Needs bpy (Blender as a module); clips that synth/render.py did not write have no such
settings, and cycles_truth() says so (CyclesTruthUnavailable).
"""
from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import numpy as np
import torch

from ..formats import colour_model, environment_light, light_size, specular_lobe
from ..formats import sequence_folder as seq
from ..render.renderer import Light

SYNTH_GENERATOR = "harp-avatar synth"


class CyclesTruthUnavailable(RuntimeError):
    """Why the Cycles truth cannot be rendered (one line)."""


def synth_settings(sequence):
    """The ClipSettings the synthetic clip was rendered with."""
    info = seq.read_sequence_info(sequence)
    metadata = info.metadata or {}
    if metadata.get("generator") != SYNTH_GENERATOR or "settings" not in metadata:
        raise CyclesTruthUnavailable(f"{sequence} was not rendered by synth/render.py: no Cycles truth")
    from synth.options import ClipSettings

    values = dict(metadata["settings"])
    values["out"] = Path(values["out"])
    for name in ("betas", "features"):
        if values.get(name) is not None:
            values[name] = tuple(values[name])
    return ClipSettings(**values), metadata


def fitted_light(description, metadata, frame):
    """The avatar's fitted light (avatar.json's) moved from the clip's hand to the one `frame`
    (a fidelity.Framing) places: the clip's lights stand around the hand at the clip's camera
    distance, the new pose's around its own."""
    light = description["light"]
    position = torch.tensor(light["position"], dtype=torch.float32)
    position = position + torch.tensor([0.0, 0.0, frame.distance - float(metadata["camera"]["distance_m"])])
    environment = environment_light.from_description(light)
    lobe = specular_lobe.from_description(light)
    return Light(position, torch.tensor(float(light["ambient"])), shadows=bool(light["shadows"]),
                 environment=None if environment is None else torch.as_tensor(environment, dtype=torch.float32),
                 specular=None if lobe is None else tuple(torch.tensor(value) for value in lobe),
                 linear=colour_model.is_linear(light), angular_radius=light_size.from_description(light))


def cycles_truth(sequence, framings):
    """[(rgb (H, W, 3) in [0, 1] over black, alpha (H, W) 0 or 1)] of the clip's true
    identity in each fidelity.Framing, rendered by Cycles with the clip's settings."""
    try:
        import bpy  # noqa: F401
    except ImportError:
        raise CyclesTruthUnavailable("bpy (Blender as a module) is not installed: no Cycles truth") from None
    from harp_addon.rig import build_hand_rig
    from synth.clip import make_person, new_scene
    from synth.lighting import setup_lighting
    from synth.material import skin_material
    from synth.passes import make_mask_scene, render_still

    settings, _ = synth_settings(sequence)
    results = []
    with tempfile.TemporaryDirectory(prefix="harp_cycles_truth_") as folder:
        folder = Path(folder)
        person = make_person(settings)
        albedo_path = seq.write_png(folder / "albedo.png", person.appearance.albedo)
        for index, frame in enumerate(framings):
            local = dataclasses.replace(settings, width=frame.size, height=frame.size, out=folder)
            scene = new_scene(local, frame.K.double().numpy())
            collection = bpy.data.collections.new("hand")
            scene.collection.children.link(collection)
            rig = build_hand_rig(person.data, person.identity.betas, person.offsets, collection=collection)
            rig.mesh.data.materials.append(skin_material(albedo_path, person.appearance.roughness,
                                                         person.identity.skin_tone, subsurface=local.subsurface,
                                                         specular_level=local.specular_level))
            setup_lighting(scene, local.lighting, local.background, target=[0.0, 0.0, frame.distance], seed=local.seed)
            mask_scene = make_mask_scene(scene, collection, scene.camera, local.mask_engine)
            rig.set_pose(frame.pose[0].double().numpy(), frame.global_orient[0].double().numpy(),
                         frame.shift.double().numpy())
            scene.cycles.seed = local.seed
            render_still(scene, folder / f"rgb{index}.png")
            render_still(mask_scene, folder / f"mask{index}.png")
            alpha = seq.read_mask(folder / f"mask{index}.png").astype(np.float64)
            rgb = seq.read_rgb(folder / f"rgb{index}.png").astype(np.float64) / 255
            results.append((rgb * alpha[..., None], alpha))
    return results
