"""The hand as an implicit surface: a smooth union of anatomical primitives (numpy).

`hand_distance(points)` returns an approximate signed distance (negative inside) of the
rest-pose hand with a wrist stub; `part_distances(points)` the distance to each part (palm,
thumb, index, middle, ring, pinky), used to label mesh vertices. The primitives are round
cones along each finger's bones, finger pads and knuckles, a rounded palm slab, the thenar
and hypothenar masses and an elliptic wrist.
"""
from __future__ import annotations

import numpy as np

from . import anatomy


def smooth_min(a, b, k):
    """Polynomial smooth minimum with blend radius k (metres)."""
    h = np.clip(k - np.abs(a - b), 0.0, None) / k
    return np.minimum(a, b) - h * h * k * 0.25


def round_cone(p, a, b, ra, rb):
    """Signed distance to the convex hull of two spheres (a, ra) and (b, rb)."""
    ba = b - a
    l2 = ba @ ba
    rr = ra - rb
    a2 = l2 - rr * rr
    il2 = 1.0 / l2
    pa = p - a
    y = pa @ ba
    z = y - l2
    x2v = pa * l2 - y[:, None] * ba
    x2 = np.einsum("ij,ij->i", x2v, x2v)
    y2 = y * y * l2
    z2 = z * z * l2
    k = np.sign(rr) * rr * rr * x2
    out = np.empty(len(p))
    cap_b = np.sign(z) * a2 * z2 > k
    cap_a = np.sign(y) * a2 * y2 < k
    side = ~(cap_b | cap_a)
    out[cap_b] = np.sqrt(x2[cap_b] + z2[cap_b]) * il2 - rb
    out[cap_a & ~cap_b] = np.sqrt(x2[cap_a & ~cap_b] + y2[cap_a & ~cap_b]) * il2 - ra
    out[side] = (np.sqrt(x2[side] * a2 * il2) + y[side] * rr) * il2 - ra
    return out


def ellipsoid(p, centre, radii):
    """Approximate signed distance to an axis-aligned ellipsoid (exact on the surface)."""
    radii = np.asarray(radii)
    q = (p - np.asarray(centre)) / radii
    return (np.linalg.norm(q, axis=1) - 1.0) * radii.min()


def rounded_polygon_slab(p, outline, half_thickness, rounding, centre_z):
    """A convex polygon (xy, counter-clockwise) extruded in z, all edges rounded."""
    xy = p[:, :2]
    inside_distance = np.full(len(p), -np.inf)
    outside = np.zeros(len(p))
    for i in range(len(outline)):
        a, b = outline[i], outline[(i + 1) % len(outline)]
        edge = b - a
        normal = np.array([edge[1], -edge[0]]) / np.linalg.norm(edge)
        inside_distance = np.maximum(inside_distance, (xy - a) @ normal)
    # exact 2D distance outside a convex polygon: distance to the nearest edge segment
    seg_dist = np.full(len(p), np.inf)
    for i in range(len(outline)):
        a, b = outline[i], outline[(i + 1) % len(outline)]
        t = np.clip(((xy - a) @ (b - a)) / ((b - a) @ (b - a)), 0, 1)
        seg_dist = np.minimum(seg_dist, np.linalg.norm(xy - (a + t[:, None] * (b - a)), axis=1))
    d2 = np.where(inside_distance > 0, seg_dist, inside_distance)
    dz = np.abs(p[:, 2] - centre_z) - half_thickness
    q = np.stack([np.maximum(d2, 0), np.maximum(dz, 0)], axis=1)
    outside = np.linalg.norm(q, axis=1)
    return outside + np.minimum(np.maximum(d2, dz), 0.0) - rounding


def elliptic_column(p, y_top):
    """The wrist: elliptic cross-sections from anatomy.FOREARM_PROFILE below y_top."""
    ax, az = anatomy.forearm_half_axes(np.minimum(p[:, 1], y_top))
    cx, cz = anatomy.WRIST_CENTRE_XZ
    q = np.stack([(p[:, 0] - cx) / ax, (p[:, 2] - cz) / az], axis=1)
    radial = (np.linalg.norm(q, axis=1) - 1.0) * np.minimum(ax, az)
    above = p[:, 1] - y_top
    return np.where(above > 0, np.hypot(np.maximum(radial, 0), above) + np.minimum(radial, 0), radial)


def _to_local(p, origin, frame, flatness):
    """Points in a finger bone's frame with the palmar axis stretched to flatten the section."""
    local = (p - origin) @ frame
    local[:, 2] /= flatness
    return local


def finger_distance(p, finger: anatomy.Finger):
    """Signed distance to one digit: three round cones, a pad and a dorsal knuckle bump."""
    points, frames = finger.chain()
    r = finger.radii
    d = np.full(len(p), np.inf)
    for bone in range(3):
        frame = frames[bone]
        a = points[bone]
        b = points[bone + 1] if bone < 2 else points[3] - r[3] * frame[:, 1]
        local = _to_local(p, a, frame, finger.flatness)
        b_local = (b - a) @ frame
        b_local[2] /= finger.flatness
        cone = round_cone(local, np.zeros(3), b_local, r[bone], r[bone + 1] if bone < 2 else r[3])
        d = np.minimum(d, cone * finger.flatness ** 0.5)
    # finger pad: a soft bulge on the palmar side of the distal phalanx
    frame = frames[2]
    pad_centre = points[2] + frame @ np.array([0.0, 0.55 * finger.lengths[2], 0.28 * r[2]])
    local = (p - pad_centre) @ frame
    pad = ellipsoid(local, np.zeros(3), (0.88 * r[2], 0.42 * finger.lengths[2], 0.78 * r[2]))
    d = smooth_min(d, pad, 0.003)
    # pads of the proximal and middle phalanges (skin folds between joints)
    for bone in (0, 1):
        frame = frames[bone]
        centre = points[bone] + frame @ np.array([0.0, 0.5 * finger.lengths[bone], 0.22 * r[bone + 1]])
        local = (p - centre) @ frame
        bulge = ellipsoid(local, np.zeros(3), (0.86 * r[bone + 1], 0.36 * finger.lengths[bone], 0.8 * r[bone + 1]))
        d = smooth_min(d, bulge, 0.003)
    # knuckle over the middle joint (dorsal side, local -z)
    frame = frames[1]
    knuckle_centre = points[1] + frame @ np.array([0.0, -0.1 * r[1], -0.25 * r[1]])
    d = smooth_min(d, np.linalg.norm(p - knuckle_centre, axis=1) - 0.86 * r[1], 0.003)
    return d


def palm_distance(p):
    """Signed distance to the palm: slab, thenar, hypothenar, metacarpal heads and wrist."""
    d = rounded_polygon_slab(p, anatomy.PALM_OUTLINE, anatomy.PALM_HALF_THICKNESS,
                             anatomy.PALM_ROUNDING, anatomy.PALM_CENTRE_Z)
    d = smooth_min(d, ellipsoid(p, *anatomy.THENAR), 0.010)
    d = smooth_min(d, ellipsoid(p, *anatomy.HYPOTHENAR), 0.008)
    for name in ("index", "middle", "ring", "pinky"):
        finger = anatomy.HAND_FINGERS[name]
        points, frames = finger.chain()
        head = points[0] + frames[0] @ np.array([0.0, -0.006, -0.0035])
        d = smooth_min(d, np.linalg.norm(p - head, axis=1) - 1.02 * finger.radii[0], 0.006)
    d = smooth_min(d, elliptic_column(p, 0.012), 0.012)
    return d


FINGER_BLEND = {"thumb": 0.013, "index": 0.0085, "middle": 0.0085, "ring": 0.0085, "pinky": 0.0085}


def part_distances(p):
    """(N, 6) distances to palm, thumb, index, middle, ring, pinky (formats PART_NAMES order)."""
    columns = [palm_distance(p)]
    for name in anatomy.FINGERS:
        columns.append(finger_distance(p, anatomy.HAND_FINGERS[name]))
    return np.stack(columns, axis=1)


def hand_distance(p, parts=None):
    """Signed distance of the whole rest hand (each digit blended into the palm)."""
    parts = part_distances(p) if parts is None else parts
    d = np.full(len(p), np.inf)
    for i, name in enumerate(anatomy.FINGERS):
        d = np.minimum(d, smooth_min(parts[:, 0], parts[:, i + 1], FINGER_BLEND[name]))
    return d
