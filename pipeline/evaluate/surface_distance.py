"""Distances from points to a triangle mesh (numpy, scipy's k-d tree): for each point the
closest point on the mesh, exactly, among the triangles whose centroids are nearest."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

CANDIDATES = 24   # nearest triangle centroids searched per point


def closest_points(points, vertices, faces, candidates=CANDIDATES):
    """(distances (N,), closest points (N, 3), face (N,), barycentric (N, 3)) from points (N, 3)
    to the mesh (vertices (V, 3), faces (F, 3)). Exact among the `candidates` triangles with the
    nearest centroids (enough where triangles are small against the distances measured)."""
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    tree = cKDTree(triangles.mean(1))
    _, near = tree.query(points, k=min(candidates, len(faces)))
    near = near.reshape(len(points), -1)
    a, b, c = (triangles[near, k] for k in range(3))                 # (N, K, 3)
    closest, barycentric = _closest_on_triangles(points[:, None], a, b, c)
    distance = np.linalg.norm(closest - points[:, None], axis=-1)
    best = distance.argmin(1)
    rows = np.arange(len(points))
    return distance[rows, best], closest[rows, best], near[rows, best], barycentric[rows, best]


def _closest_on_triangles(p, a, b, c):
    """Closest points on triangles (a, b, c) to p (broadcast, (..., 3)) and their barycentric
    coordinates (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    denominator = va + vb + vc
    v = vb / np.where(denominator == 0, 1, denominator)
    w = vc / np.where(denominator == 0, 1, denominator)
    bary = np.stack([1 - v - w, v, w], -1)                           # inside the face
    regions = [  # (condition, barycentric) from the vertex and edge regions, first match wins
        ((d1 <= 0) & (d2 <= 0), _bary(1, 0, 0, d1)),
        ((d3 >= 0) & (d4 <= d3), _bary(0, 1, 0, d1)),
        ((d6 >= 0) & (d5 <= d6), _bary(0, 0, 1, d1)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), _edge(d1 / _safe(d1 - d3), 0, 1)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), _edge(d2 / _safe(d2 - d6), 0, 2)),
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), _edge((d4 - d3) / _safe((d4 - d3) + (d5 - d6)), 1, 2)),
    ]
    for condition, value in reversed(regions):
        bary = np.where(condition[..., None], value, bary)
    closest = bary[..., :1] * a + bary[..., 1:2] * b + bary[..., 2:] * c
    return closest, bary


def _dot(u, v):
    return (u * v).sum(-1)


def _safe(x):
    return np.where(x == 0, 1, x)


def _bary(x, y, z, like):
    return np.broadcast_to(np.array([x, y, z], dtype=np.float64), like.shape + (3,))


def _edge(t, i, j):
    """Barycentric coordinates of the point a fraction t from corner i to corner j."""
    bary = np.zeros(t.shape + (3,))
    bary[..., i], bary[..., j] = 1 - t, t
    return bary
