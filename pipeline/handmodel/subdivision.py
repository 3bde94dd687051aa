"""Midpoint (1 -> 4) subdivision of a hand model: the mesh the fit optimises.

Every edge gets a vertex at its midpoint; positions, shape directions and skinning weights of
that vertex are the mean of the edge's two ends (so the subdivided rest shape is exactly the
midpoint subdivision of the shaped template for every beta); UVs are split the same way on the
UV edges, so seams stay seams. Weights that gain more than four influences are pruned back.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import torch

from .skinning_weights import prune_weights


def midpoint_edges(faces, shared_count=0):
    """Unique undirected edges (E, 2) and, per face, the index of its three edges (F, 3):
    edge k of a face joins corners k and k+1. Edges between two of the first `shared_count`
    points come first, so a shared leading block of points stays a shared leading block."""
    corners = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)
    edges, inverse = np.unique(np.sort(corners, axis=1), axis=0, return_inverse=True)
    order = np.argsort(edges[:, 1] >= shared_count, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return edges[order], rank[inverse.reshape(-1, 3)]


def subdivide_faces(faces, num_points, shared_count=0):
    """New faces (4F, 3) and the edges whose midpoints become points num_points..."""
    edges, face_edges = midpoint_edges(faces, shared_count)
    m = face_edges + num_points
    a, b, c = faces.T
    ab, bc, ca = m.T
    new_faces = np.concatenate([
        np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
        np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)])
    return new_faces.astype(np.int32), edges


def _subdivision_order(data):
    """(the new faces (4F, 3), the edges split (E, 2), and the order of the new points: the
    shared vertices, their edge midpoints, the other vertices, the other midpoints)."""
    shared, count = data.shared_vertex_count, data.num_vertices
    faces, edges = subdivide_faces(data.faces, count, shared)
    shared_edges = int((edges < shared).all(axis=1).sum())
    order = np.concatenate([np.arange(shared), count + np.arange(shared_edges),
                            np.arange(shared, count), count + np.arange(shared_edges, len(edges))])
    return faces, edges, order


def midpoint_parents(data):
    """(V', 2) for every point of subdivide_model_data(data), the two points of `data` it is the
    mean of (a vertex kept: itself twice). A value per point of `data` carries over to the
    subdivided mesh as the mean of its two parents' values."""
    _, edges, order = _subdivision_order(data)
    kept = np.repeat(np.arange(data.num_vertices)[:, None], 2, axis=1)
    return np.concatenate([kept, edges])[order]


def unsubdivided_faces(faces):
    """(F / 4, 3) the faces of the mesh before one subdivision, in the subdivided mesh's point
    numbering, from the subdivided faces (4F, 3) alone: subdivide_faces puts each face's corner
    a first in the first quarter, b second in the second, c third in the third."""
    count = len(faces) // 4
    corners = (faces[:count, 0], faces[count:2 * count, 1], faces[2 * count:3 * count, 2])
    return (torch.stack(corners, 1) if isinstance(faces, torch.Tensor) else np.stack(corners, axis=1))


def subdivide_model_data(data):
    """A new HandModelData with every face split in four."""
    faces, edges, order = _subdivision_order(data)
    faces_uv, uv_edges = subdivide_faces(data.faces_uv, len(data.uvs))
    shared = data.shared_vertex_count
    shared_edges = int((edges < shared).all(axis=1).sum())
    position = np.empty_like(order)
    position[order] = np.arange(len(order))

    def extend(array):
        return np.concatenate([array, 0.5 * (array[edges[:, 0]] + array[edges[:, 1]])])[order]

    skin_indices, skin_weights = prune_weights(extend(data.dense_weights()))
    parts_a, parts_b = data.vertex_parts[edges[:, 0]], data.vertex_parts[edges[:, 1]]
    parts = np.concatenate([data.vertex_parts, np.where(parts_a == parts_b, parts_a, 0)])[order]
    uvs = np.concatenate([data.uvs, 0.5 * (data.uvs[uv_edges[:, 0]] + data.uvs[uv_edges[:, 1]])])
    return dataclasses.replace(
        data, vertices=extend(data.vertices), faces=position[faces].astype(np.int32), uvs=uvs,
        faces_uv=faces_uv, skin_indices=skin_indices, skin_weights=skin_weights,
        shapedirs=extend(data.shapedirs), vertex_parts=parts.astype(np.int8),
        shared_vertex_count=shared + shared_edges,
        metadata={**data.metadata, "subdivided": data.metadata.get("subdivided", 0) + 1})
