"""Triangle meshes of the template: the implicit hand meshed, cut at the wrist, then closed.

The hand surface is extracted from `implicit_hand` with marching cubes, decimated with quadric
error metrics, remeshed to even edge lengths and relaxed; it ends at the wrist in a ring of vertices
that lie exactly in the plane y = WRIST_CUT_Y. Both modes share this surface (it is the
leading block of vertices): hand-only mode closes the ring with a flat disc, hand+forearm mode
continues it with rings down to the elbow and closes it with a dome.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from . import anatomy, implicit_hand, remesh

WRIST_RING_SIZE = 28
FOREARM_RING_SPACING = 0.016


@dataclasses.dataclass
class TemplateMesh:
    vertices: np.ndarray       # (V, 3)
    faces: np.ndarray          # (F, 3) int32, outward counter-clockwise
    parts: np.ndarray          # (V,) int8 index into PART_NAMES
    shared_vertex_count: int   # leading vertices that both modes share


def _evaluate_grid(lo, hi, voxel):
    axes = [np.arange(lo[i], hi[i] + voxel / 2, voxel) for i in range(3)]
    gx, gy, gz = np.meshgrid(*axes, indexing="ij")
    points = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    values = np.empty(len(points))
    chunk = 400_000
    for start in range(0, len(points), chunk):
        values[start:start + chunk] = implicit_hand.hand_distance(points[start:start + chunk])
    return values.reshape(gx.shape), np.array([a[0] for a in axes])


def _marching_cubes(voxel):
    from skimage.measure import marching_cubes

    lo = np.array([-0.055, anatomy.WRIST_CUT_Y - 0.012, -0.036])
    hi = np.array([0.110, 0.200, 0.075])
    volume, origin = _evaluate_grid(lo, hi, voxel)
    vertices, faces, _, _ = marching_cubes(volume, level=0.0, spacing=(voxel,) * 3,
                                           gradient_direction="descent")
    return vertices + origin, faces.astype(np.int64)


def _decimate(vertices, faces, target_faces):
    import pyfqmr

    simplifier = pyfqmr.Simplify()
    simplifier.setMesh(vertices, faces)
    simplifier.simplify_mesh(target_count=target_faces, aggressiveness=5, preserve_border=True,
                             verbose=False, max_iterations=200)
    v, f, _ = simplifier.getMesh()
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def vertex_neighbours(faces, n):
    """Sparse (n, n) adjacency matrix of the mesh edges (scipy CSR, 1 per edge)."""
    import scipy.sparse as sp

    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    adjacency = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    adjacency.data[:] = 1.0
    return adjacency


def _project_to_surface(points, iterations=4):
    """Move points onto the zero level set along the implicit function's gradient."""
    eps = 1e-5
    for _ in range(iterations):
        d = implicit_hand.hand_distance(points)
        grad = np.stack([(implicit_hand.hand_distance(points + eps * np.eye(3)[i]) - d) / eps
                         for i in range(3)], axis=1)
        grad /= np.maximum(np.linalg.norm(grad, axis=1, keepdims=True) ** 2, 1e-12)
        points = points - d[:, None] * grad
    return points


def _relax(vertices, faces, fixed, iterations=6, step=0.5):
    """Tangential smoothing (even out triangle shapes) with re-projection onto the surface."""
    adjacency = vertex_neighbours(faces, len(vertices))
    degree = np.asarray(adjacency.sum(1)).ravel()
    for _ in range(iterations):
        mean = adjacency @ vertices / degree[:, None]
        normals = vertex_normals(vertices, faces)
        delta = mean - vertices
        delta -= np.einsum("ij,ij->i", delta, normals)[:, None] * normals
        moved = vertices + step * delta
        moved[fixed] = vertices[fixed]
        free = ~fixed
        moved[free] = _project_to_surface(moved[free])
        vertices = moved
    return vertices


def vertex_normals(vertices, faces):
    """Area-weighted unit vertex normals."""
    face_normals = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                            vertices[faces[:, 2]] - vertices[faces[:, 0]])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-20)


def boundary_loops(faces):
    """Boundary loops as lists of vertex indices, ordered as the faces traverse their edges."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edge_set = set(map(tuple, edges))
    following = {}
    for a, b in edges:
        if (b, a) not in edge_set:
            if a in following:
                raise ValueError("the boundary is not a set of simple loops")
            following[a] = b
    loops = []
    while following:
        start, _ = next(iter(following.items()))
        loop = [start]
        while True:
            nxt = following.pop(loop[-1])
            if nxt == start:
                break
            loop.append(nxt)
        loops.append(loop)
    return loops


def _remove_pinched_boundary(faces):
    """Drop boundary faces at vertices where the boundary touches itself, until none is left."""
    while True:
        edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        edge_set = set(map(tuple, edges))
        on_boundary = np.array([(b, a) not in edge_set for a, b in edges]).reshape(3, -1).T
        starts = edges[on_boundary.T.ravel()][:, 0]
        values, counts = np.unique(starts, return_counts=True)
        pinched = values[counts > 1]
        if len(pinched) == 0:
            return faces
        drop = np.isin(faces, pinched).any(axis=1) & on_boundary.any(axis=1)
        faces = faces[~drop]


def _boundary_mask(faces, count):
    mask = np.zeros(count, dtype=bool)
    for loop in boundary_loops(faces):
        mask[loop] = True
    return mask


def _drop_unused(vertices, faces):
    used = np.unique(faces)
    remap = -np.ones(len(vertices), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces]


def _angles(points):
    cx, cz = anatomy.WRIST_CENTRE_XZ
    return np.arctan2(points[:, 2] - cz, points[:, 0] - cx)


def _wrist_section(y, angles):
    """Points of the implicit surface in the plane at height y, one per angle (bisection)."""
    cx, cz = anatomy.WRIST_CENTRE_XZ
    directions = np.stack([np.cos(angles), np.zeros_like(angles), np.sin(angles)], axis=1)
    centre = np.array([cx, y, cz])
    lo = np.zeros(len(angles))
    hi = np.full(len(angles), 0.06)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        inside = implicit_hand.hand_distance(centre + mid[:, None] * directions) < 0
        lo = np.where(inside, mid, lo)
        hi = np.where(inside, hi, mid)
    return centre + (0.5 * (lo + hi))[:, None] * directions


def zip_loops(loop_a, angles_a, loop_b, angles_b):
    """Triangles joining two closed loops that run the same way around the wrist axis.

    loop_a is the boundary of the existing surface, ordered as its faces traverse it; the new
    triangles traverse loop_a backwards and loop_b forwards (so loop_b must be closed on its
    other side by faces that traverse it backwards).
    """
    na, nb = len(loop_a), len(loop_b)

    def wrapped(x):
        return np.angle(np.exp(1j * x))

    steps_a = wrapped(np.diff(np.r_[angles_a, angles_a[0]]))
    sense = np.sign(steps_a.sum())
    start_b = int(np.argmin(np.abs(wrapped(angles_b - angles_a[0]))))
    b_index = np.roll(np.arange(nb), -start_b)
    steps_b = wrapped(np.diff(np.r_[angles_b[b_index], angles_b[b_index[0]]]))
    ua = np.r_[0.0, np.cumsum(steps_a * sense)]
    ub = wrapped(angles_b[b_index[0]] - angles_a[0]) * sense + np.r_[0.0, np.cumsum(steps_b * sense)]
    triangles = []
    i = j = 0
    while i < na or j < nb:
        a, b = loop_a[i % na], loop_b[b_index[j % nb]]
        advance_a = j >= nb or (i < na and ua[i + 1] <= ub[j + 1])
        if advance_a:
            triangles.append((loop_a[(i + 1) % na], a, b))
            i += 1
        else:
            triangles.append((a, b, loop_b[b_index[(j + 1) % nb]]))
            j += 1
    return np.array(triangles, dtype=np.int64)


def bridge_rings(ring_a, ring_b):
    """Quads (as triangle pairs) between two rings of equal size running the same way."""
    ring_a, ring_b = np.asarray(ring_a), np.asarray(ring_b)
    a0, a1 = ring_a, np.roll(ring_a, -1)
    b0, b1 = ring_b, np.roll(ring_b, -1)
    first = np.stack([a1, a0, b0], axis=1)
    second = np.stack([a1, b0, b1], axis=1)
    return np.concatenate([first, second])


def close_ring(ring, pole):
    """A fan closing a ring that its neighbouring faces traverse forwards."""
    ring = np.asarray(ring)
    return np.stack([np.roll(ring, -1), ring, np.full(len(ring), pole)], axis=1)


def label_parts(vertices, faces):
    """Part of each vertex (PART_NAMES index): the nearest primitive group; vertices on an
    edge joining two different digits are web skin and belong to the palm."""
    parts = np.argmin(implicit_hand.part_distances(vertices), axis=1).astype(np.int8)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    a, b = parts[edges[:, 0]], parts[edges[:, 1]]
    across = (a > 0) & (b > 0) & (a != b)
    parts[edges[across].ravel()] = 0
    return parts


def hand_surface(voxel=0.0011, target_faces=1000, edge_length=0.0068):
    """The shared hand surface: (vertices, faces, wrist ring indices)."""
    vertices, faces = _marching_cubes(voxel)
    vertices, faces = _decimate(vertices, faces, target_faces)
    vertices, faces = remesh.split_long_edges(vertices, faces, 4 / 3 * edge_length,
                                               _project_to_surface)
    vertices, faces = remesh.flip_to_delaunay(vertices, faces)
    vertices = _relax(vertices, faces, _boundary_mask(faces, len(vertices)))
    vertices, faces = remesh.flip_to_delaunay(vertices, faces)
    # cut off everything below the wrist band, leaving one boundary loop
    cut = anatomy.WRIST_CUT_Y + 0.004
    keep = (vertices[faces][:, :, 1] > cut).all(axis=1)
    vertices, faces = _drop_unused(vertices, _remove_pinched_boundary(faces[keep]))
    loops = boundary_loops(faces)
    if len(loops) != 1:
        raise RuntimeError(f"the wrist cut left {len(loops)} boundary loops instead of one")
    loop = np.array(loops[0])
    fixed = np.zeros(len(vertices), dtype=bool)
    fixed[loop] = True
    vertices = _relax(vertices, faces, fixed)
    # the exact wrist ring in the cut plane, then a strip joining it to the jagged loop
    ring_angles = np.linspace(0, 2 * np.pi, WRIST_RING_SIZE, endpoint=False)
    loop_angles = _angles(vertices[loop])
    sense = np.sign(np.sum(np.angle(np.exp(1j * np.diff(np.r_[loop_angles, loop_angles[0]])))))
    ring_angles = ring_angles * sense
    ring_points = _wrist_section(anatomy.WRIST_CUT_Y, ring_angles)
    ring = np.arange(len(vertices), len(vertices) + WRIST_RING_SIZE)
    strip = zip_loops(loop, loop_angles, ring, ring_angles)
    vertices = np.concatenate([vertices, ring_points])
    faces = np.concatenate([faces, strip])
    return vertices, faces, ring


def _section_scale(ring_points, y):
    """Ring at height y: the wrist ring's shape morphing into the forearm's ellipse."""
    cx, cz = anatomy.WRIST_CENTRE_XZ
    ax0, az0 = anatomy.forearm_half_axes(anatomy.WRIST_CUT_Y)
    ax, az = anatomy.forearm_half_axes(y)
    fade = np.clip((y - (anatomy.WRIST_CUT_Y - 0.04)) / 0.04, 0, 1)
    rel = ring_points[:, [0, 2]] - np.array([cx, cz])
    angle = np.arctan2(rel[:, 1] / az0, rel[:, 0] / ax0)
    ellipse0 = np.stack([ax0 * np.cos(angle), az0 * np.sin(angle)], axis=1)
    ellipse = np.stack([ax * np.cos(angle), az * np.sin(angle)], axis=1)
    section = ellipse + fade * (rel - ellipse0) * np.array([ax / ax0, az / az0])
    return np.stack([section[:, 0] + cx, np.full(len(rel), y), section[:, 1] + cz], axis=1)


def build_template_meshes():
    """Both modes: {'hand': TemplateMesh, 'arm': TemplateMesh}."""
    surface_vertices, surface_faces, ring = hand_surface()
    parts = label_parts(surface_vertices, surface_faces)
    parts[ring] = 0
    shared = len(surface_vertices)
    ring_points = surface_vertices[ring]
    cx, cz = anatomy.WRIST_CENTRE_XZ
    centre = np.array([cx, anatomy.WRIST_CUT_Y, cz])
    meshes = {}

    # hand-only: a flat disc of two inner rings and a centre vertex
    cap_rings = [centre + s * (ring_points - centre) for s in (0.68, 0.36)]
    cap_vertices = np.concatenate(cap_rings + [centre[None]])
    n = WRIST_RING_SIZE
    r1 = shared + np.arange(n)
    r2 = shared + n + np.arange(n)
    pole = shared + 2 * n
    cap_faces = np.concatenate([bridge_rings(ring, r1), bridge_rings(r1, r2), close_ring(r2, pole)])
    meshes["hand"] = TemplateMesh(
        np.concatenate([surface_vertices, cap_vertices]),
        np.concatenate([surface_faces, cap_faces]).astype(np.int32),
        np.concatenate([parts, np.full(len(cap_vertices), 7, np.int8)]), shared)

    # hand + forearm: rings down to the elbow, then a dome
    length = anatomy.WRIST_CUT_Y - anatomy.FOREARM_END_Y
    count = int(round(length / FOREARM_RING_SPACING))
    heights = anatomy.WRIST_CUT_Y - length * np.arange(1, count + 1) / count
    sections = [_section_scale(ring_points, y) for y in heights]
    end = sections[-1]
    end_centre = np.array([cx, anatomy.FOREARM_END_Y, cz])
    dome_depth = 0.022
    for angle in np.radians([32, 60, 80]):
        section = end_centre + np.cos(angle) * (end - end_centre)
        section[:, 1] = anatomy.FOREARM_END_Y - dome_depth * np.sin(angle)
        sections.append(section)
    arm_vertices = np.concatenate(sections + [(end_centre - [0, dome_depth, 0])[None]])
    rings = [ring] + [shared + k * n + np.arange(n) for k in range(len(sections))]
    arm_faces = [bridge_rings(rings[k], rings[k + 1]) for k in range(len(rings) - 1)]
    arm_faces.append(close_ring(rings[-1], shared + len(sections) * n))
    meshes["arm"] = TemplateMesh(
        np.concatenate([surface_vertices, arm_vertices]),
        np.concatenate([surface_faces] + arm_faces).astype(np.int32),
        np.concatenate([parts, np.full(len(arm_vertices), 6, np.int8)]), shared)
    return meshes
