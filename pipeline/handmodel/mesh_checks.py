"""Measurements of mesh validity: 2-manifold, orientation, self-intersection, inversion, volume."""
from __future__ import annotations

import numpy as np


def edge_face_counts(faces):
    """Map undirected edge -> number of faces using it, and directed edge multiplicity."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    undirected = np.sort(directed, axis=1)
    _, undirected_counts = np.unique(undirected, axis=0, return_counts=True)
    _, directed_counts = np.unique(directed, axis=0, return_counts=True)
    return undirected_counts, directed_counts


def is_closed_oriented_manifold(faces, num_vertices):
    """True if every edge has exactly two faces traversing it in opposite directions, and every
    vertex has a single fan of faces around it (no pinched vertices)."""
    undirected_counts, directed_counts = edge_face_counts(faces)
    if not (undirected_counts == 2).all() or not (directed_counts == 1).all():
        return False
    # vertex links must be single cycles: count connected components of each vertex's fan
    following = {}
    for a, b, c in faces:
        for v, p, q in ((a, b, c), (b, c, a), (c, a, b)):
            following.setdefault(v, {})[p] = q
    if len(following) != num_vertices:
        return False
    for links in following.values():
        start = next(iter(links))
        current, steps = links[start], 1
        while current != start and steps <= len(links):
            current = links.get(current)
            steps += 1
            if current is None:
                return False
        if steps != len(links):
            return False
    return True


def signed_volume(vertices, faces):
    """Enclosed volume (positive when faces are outward counter-clockwise)."""
    a, b, c = (vertices[..., faces[:, k], :] for k in range(3))
    return np.einsum("...i,...i->...", a, np.cross(b, c)).sum(-1) / 6.0


def face_normals(vertices, faces, normalise=True):
    n = np.cross(vertices[..., faces[:, 1], :] - vertices[..., faces[:, 0], :],
                 vertices[..., faces[:, 2], :] - vertices[..., faces[:, 0], :])
    if normalise:
        n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
    return n


def inverted_faces(rest_vertices, deformed_vertices, faces, threshold=0.0):
    """Boolean mask of faces whose normal turned by more than 90 degrees (or collapsed)."""
    return np.einsum("...i,...i->...", face_normals(rest_vertices, faces),
                     face_normals(deformed_vertices, faces)) <= threshold


def _segment_hits_triangles(p0, p1, a, b, c, eps=1e-12):
    """Vectorised Moller-Trumbore: does segment p0->p1 cross triangle abc (strict interior)?"""
    direction = p1 - p0
    e1, e2 = b - a, c - a
    h = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > eps
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = p0 - a
    u = inv * np.einsum("ij,ij->i", s, h)
    q = np.cross(s, e1)
    v = inv * np.einsum("ij,ij->i", direction, q)
    t = inv * np.einsum("ij,ij->i", e2, q)
    return ok & (u > 0) & (v > 0) & (u + v < 1) & (t > 0) & (t < 1)


def self_intersections(vertices, faces):
    """Pairs of faces (sharing no vertex) that intersect; an empty (0, 2) array when clean."""
    from scipy.spatial import cKDTree

    tri = vertices[faces]
    centroids = tri.mean(1)
    radius = np.linalg.norm(tri - centroids[:, None], axis=2).max(1)
    pairs = cKDTree(centroids).query_pairs(2 * radius.max(), output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    close = np.linalg.norm(centroids[pairs[:, 0]] - centroids[pairs[:, 1]], axis=1) <= \
        radius[pairs[:, 0]] + radius[pairs[:, 1]]
    pairs = pairs[close]
    share = (faces[pairs[:, 0]][:, :, None] == faces[pairs[:, 1]][:, None, :]).any((1, 2))
    pairs = pairs[~share]
    hit = np.zeros(len(pairs), dtype=bool)
    for first, second in ((0, 1), (1, 0)):
        ta, tb = tri[pairs[:, first]], tri[pairs[:, second]]
        for k in range(3):
            hit |= _segment_hits_triangles(ta[:, k], ta[:, (k + 1) % 3], tb[:, 0], tb[:, 1], tb[:, 2])
    return pairs[hit]


def triangle_min_angles(vertices, faces):
    """Smallest interior angle of every face, degrees."""
    tri = vertices[faces]
    angles = []
    for k in range(3):
        u = tri[:, (k + 1) % 3] - tri[:, k]
        w = tri[:, (k + 2) % 3] - tri[:, k]
        cos = np.einsum("ij,ij->i", u, w) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-30)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.min(angles, axis=0)
