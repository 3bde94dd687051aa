"""The surface's regularisers over a batch of posed meshes (appendix C.3, Table C.1): the uniform
Laplacian, the normal consistency of neighbouring faces and the edge lengths' change (the
as-rigid-as-possible term of the reference implementation).

Each is a mean over every mesh of the batch, so they are computed on all of a batch's meshes at
once, vertex-major: the batch's vertices (B, V, 3) laid out as (V, B, 3), so that gathering a
vertex (or a face) takes one contiguous row of all B meshes. The Laplacian and the edge vectors
are sparse operators (render/sparse_operator.py) applied to that layout, whose backward pass is
their transpose applied to the gradient; gathers by index scatter their gradients back one row at
a time, which made these terms about a quarter of a shaded step at `preview`'s size
(docs/performance.md).
"""
from __future__ import annotations

import torch

from ..render.sparse_operator import SparseOperator, vertex_major
from ..render.vector_ops import cross3, normalized


class SurfaceRegularisers:
    """The Laplacian, normal-consistency and edge-length terms of one mesh topology: `faces` (F, 3),
    its undirected `edges` (E, 2), the pairs of faces that share an edge `face_pairs` (P, 2) (an open
    boundary's edges excluded), over `vertex_count` vertices."""

    def __init__(self, faces, edges, face_pairs, vertex_count, dtype=torch.float32, device=None):
        device = faces.device if device is None else device
        self.faces, self.edges, self.face_pairs = faces.to(device), edges.to(device), face_pairs.to(device)
        both = torch.cat([edges, edges.flip(1)])
        count = torch.zeros(vertex_count, dtype=torch.float64, device=edges.device)
        count = count.index_add(0, both[:, 0], torch.ones(len(both), dtype=torch.float64, device=edges.device))
        vertices = torch.arange(vertex_count, device=edges.device)
        # mean of the neighbours minus the vertex: (A / degree) - I, one row per vertex
        self.laplacian = SparseOperator(torch.cat([both[:, 0], vertices]), torch.cat([both[:, 1], vertices]),
                                        torch.cat([1.0 / count.clamp(min=1)[both[:, 0]],
                                                   -torch.ones(vertex_count, dtype=torch.float64, device=edges.device)]),
                                        (vertex_count, vertex_count), dtype=dtype, device=device)
        rows = torch.arange(len(edges), device=edges.device)
        ones = torch.ones(len(edges), dtype=torch.float64, device=edges.device)
        self.edge_vectors = SparseOperator(torch.cat([rows, rows]), torch.cat([edges[:, 0], edges[:, 1]]),
                                           torch.cat([ones, -ones]), (len(edges), vertex_count), dtype=dtype, device=device)

    def uniform_laplacian(self, vertices):
        """(B, V, 3) the uniform Laplacian (mean of the neighbours minus the vertex) of (B, V, 3)
        vertices."""
        batch, count = vertices.shape[:2]
        return self.laplacian(vertex_major(vertices)).view(count, batch, 3).transpose(0, 1)

    def laplacian_loss(self, vertices):
        """Mean length of the uniform Laplacian over every vertex of every mesh: zero on a flat
        regular grid's interior."""
        batch, count = vertices.shape[:2]
        return self.laplacian(vertex_major(vertices)).view(count, batch, 3).norm(dim=-1).mean()

    def edge_lengths(self, vertices):
        """(B, E) the length of every edge of every mesh (B, V, 3)."""
        batch = vertices.shape[0]
        vectors = self.edge_vectors(vertex_major(vertices))
        return vectors.view(-1, batch, 3).norm(dim=-1).transpose(0, 1)

    def edge_length_loss(self, vertices, reference_lengths):
        """Mean squared change of the edge lengths (metres^2) of (B, V, 3) vertices against
        `reference_lengths` (B, E) (edge_lengths of the reference meshes): zero under rigid motion."""
        return (self.edge_lengths(vertices) - reference_lengths).square().mean()

    def normal_consistency_loss(self, vertices):
        """Mean of 1 - cos(angle) between the normals of faces that share an edge, over every mesh."""
        rows = vertices.transpose(0, 1).contiguous()                               # (V, B, 3)
        v0, v1, v2 = (rows.index_select(0, self.faces[:, k]) for k in range(3))
        normals = normalized(cross3(v1 - v0, v2 - v0))
        return (1 - (normals.index_select(0, self.face_pairs[:, 0])
                     * normals.index_select(0, self.face_pairs[:, 1])).sum(-1)).mean()
