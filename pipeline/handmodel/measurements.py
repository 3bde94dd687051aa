"""Measured anatomy and quality figures of the model (printed by `harp model info`)."""
from __future__ import annotations

import numpy as np
import torch

from ..formats import hand_model_file as fmt
from . import anatomy, mesh_checks
from .lbs import HandModel
from .subdivision import midpoint_edges
from .uv_atlas import texel_density_spread, uv_mask


def hand_length(data):
    """Wrist keypoint to middle-finger tip, metres."""
    k = list(data.keypoint_names)
    return float(np.linalg.norm(data.keypoints[k.index("middle_tip")] - data.keypoints[k.index("wrist")]))


def palm_width(data, band=0.004):
    """Breadth across the knuckles: x extent of palm and finger skin (no thumb) at MCP height."""
    k = list(data.keypoint_names)
    mcp_y = np.mean([data.keypoints[k.index(f"{n}_mcp")][1] for n in ("index", "middle", "ring", "pinky")])
    thumb = fmt.PART_NAMES.index("thumb")
    near = (np.abs(data.vertices[:, 1] - mcp_y) < band) & (data.vertex_parts != thumb)
    x = data.vertices[near, 0]
    return float(x.max() - x.min())


def segment_lengths(data):
    """{finger: (first, second, third bone length)} from joints and tip keypoints, metres."""
    k = list(data.keypoint_names)
    result = {}
    for name in anatomy.FINGERS:
        first = "cmc" if name == "thumb" else "mcp"
        names = [first, "mcp", "ip", "tip"] if name == "thumb" else ["mcp", "pip", "dip", "tip"]
        points = [data.keypoints[k.index(f"{name}_{n}")] for n in names]
        result[name] = tuple(float(np.linalg.norm(points[i + 1] - points[i])) for i in range(3))
    return result


def bend_volume_loss(mode="hand", joint=1, degrees=90.0, folder=None):
    """Volume lost when one joint flexes by `degrees`, as (cm^3, % of that digit's volume)."""
    model = HandModel.load(mode, dtype=torch.float64, folder=folder)
    pose = torch.zeros(1, 16, 3, dtype=torch.float64)
    pose[0, joint, 0] = np.radians(degrees)
    faces = model.data.faces
    rest = mesh_checks.signed_volume(model.data.vertices, faces)
    with torch.no_grad():
        bent = mesh_checks.signed_volume(model(pose=pose).vertices[0].numpy(), faces)
    digit = next(name for name, joints in anatomy.FINGER_JOINTS.items() if joint in joints)
    finger = anatomy.HAND_FINGERS[digit]
    r = np.array(finger.radii)
    digit_volume = sum(np.pi * ((r[i] + r[i + 1]) / 2) ** 2 * finger.lengths[i] for i in range(3))
    lost = rest - bent
    return lost * 1e6, 100.0 * lost / digit_volume


def anatomy_report(folder=None):
    """Printable figures of the model files in `folder` (default: the shipped model)."""
    lines = []
    for mode in fmt.MODES:
        data = fmt.load_hand_model(fmt.model_path(mode, folder))
        v, f = data.vertices, data.faces
        edges, _ = midpoint_edges(f)
        lines.append(f"[{mode}] {len(v)} vertices, {len(f)} faces; subdivided: "
                     f"{len(v) + len(edges)} vertices, {4 * len(f)} faces")
        lines.append(f"  closed oriented 2-manifold: {mesh_checks.is_closed_oriented_manifold(f, len(v))}, "
                     f"self-intersecting face pairs: {len(mesh_checks.self_intersections(v, f))}, "
                     f"volume {mesh_checks.signed_volume(v, f) * 1e6:.0f} cm^3")
        lines.append(f"  UV: {data.metadata.get('uv_charts')} charts, "
                     f"{uv_mask(data.uvs, data.faces_uv, 512).mean() * 100:.0f}% of a 512 atlas used, "
                     f"texel density spread {texel_density_spread(v, f, data.uvs, data.faces_uv) * 100:.1f}%")
    data = fmt.load_hand_model(fmt.model_path("hand", folder))
    lines.append(f"hand length (wrist to middle tip): {hand_length(data) * 100:.1f} cm")
    lines.append(f"palm width across the knuckles: {palm_width(data) * 100:.1f} cm")
    for name, lengths in segment_lengths(data).items():
        ratios = np.array(lengths) / lengths[0]
        lines.append(f"{name:>7}: bones {' / '.join(f'{x * 100:.1f}' for x in lengths)} cm, "
                     f"ratio 1 : {ratios[1]:.2f} : {ratios[2]:.2f}")
    for joint, label in ((1, "index MCP"), (2, "index PIP"), (13, "thumb CMC")):
        cm3, percent = bend_volume_loss("hand", joint, 90.0 if joint != 13 else 55.0, folder)
        angle = 90 if joint != 13 else 55
        lines.append(f"volume lost bending {label} {angle} deg: {cm3:.2f} cm^3 ({percent:.1f}% of the digit)")
    return "\n".join(lines)


def joint_limits_markdown():
    """The joint-limit table of docs/hand_model.md (degrees), generated from the anatomy."""
    limits = anatomy.joint_limits_deg()
    rows = ["| joint | flexion (x) | twist (y) | deviation (z) |", "|---|---|---|---|"]
    for j, name in enumerate(fmt.JOINT_NAMES):
        cells = [f"{lo:g} to {hi:g}" for lo, hi in limits[j]]
        rows.append(f"| {j} {name} | " + " | ".join(cells) + " |")
    return "\n".join(rows)
