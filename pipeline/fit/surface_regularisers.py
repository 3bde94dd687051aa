"""The surface's regularisers over a batch of posed meshes (appendix C.3, Table C.1): the uniform
Laplacian, the normal consistency of neighbouring faces and the edge lengths' change (the
as-rigid-as-possible term of the reference implementation).

Each is a mean over every mesh of the batch, so they are computed on all of a batch's meshes at
once, vertex-major: the batch's vertices (B, V, 3) laid out as (V, B, 3), so that gathering a
vertex (or a face) takes one contiguous row of all B meshes. The Laplacian and the edge vectors
are sparse matrices (CSR) applied to that layout, whose backward pass is their transpose applied
to the gradient; gathers by index scatter their gradients back one row at a time, which made these
terms about a quarter of a shaded step at `preview`'s size (docs/performance.md). Sparse CSR
products with gradients run on the CPU and on CUDA alike.
"""
from __future__ import annotations

import warnings

import torch
import torch.nn.functional as F


def _difference_matrix(plus, minus, columns, dtype, device):
    """(N, columns) CSR matrix whose row i takes column plus[i] minus column minus[i]."""
    rows = torch.arange(len(plus), device=plus.device)
    matrix = torch.sparse_coo_tensor(torch.stack([torch.cat([rows, rows]), torch.cat([plus, minus])]),
                                     torch.cat([torch.ones(len(plus)), -torch.ones(len(plus))]).to(plus.device),
                                     (len(plus), columns), check_invariants=True)
    return _csr(matrix, dtype, device)


def _csr(matrix, dtype, device):
    with warnings.catch_warnings():     # torch calls its sparse CSR support "beta" on every construction
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return matrix.coalesce().to(dtype=dtype, device=device).to_sparse_csr()


def _vertex_major(vertices):
    """(V, B * 3) the batch's vertices (B, V, 3), each vertex's row holding it in every mesh."""
    return vertices.transpose(0, 1).reshape(vertices.shape[1], -1)


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
        # mean of the neighbours minus the vertex: (A / degree) - I, one row per vertex
        rows = torch.cat([both[:, 0], torch.arange(vertex_count, device=edges.device)])
        columns = torch.cat([both[:, 1], torch.arange(vertex_count, device=edges.device)])
        values = torch.cat([1.0 / count.clamp(min=1)[both[:, 0]],
                            -torch.ones(vertex_count, dtype=torch.float64, device=edges.device)])
        laplacian = torch.sparse_coo_tensor(torch.stack([rows, columns]), values, (vertex_count, vertex_count),
                                            check_invariants=True)
        self.laplacian_matrix = _csr(laplacian, dtype, device)
        self.edge_matrix = _difference_matrix(edges[:, 0], edges[:, 1], vertex_count, dtype, device)

    def uniform_laplacian(self, vertices):
        """(B, V, 3) the uniform Laplacian (mean of the neighbours minus the vertex) of (B, V, 3)
        vertices."""
        batch, count = vertices.shape[:2]
        return torch.sparse.mm(self.laplacian_matrix, _vertex_major(vertices)).view(count, batch, 3).transpose(0, 1)

    def laplacian_loss(self, vertices):
        """Mean length of the uniform Laplacian over every vertex of every mesh: zero on a flat
        regular grid's interior."""
        batch, count = vertices.shape[:2]
        return torch.sparse.mm(self.laplacian_matrix, _vertex_major(vertices)).view(count, batch, 3).norm(dim=-1).mean()

    def edge_lengths(self, vertices):
        """(B, E) the length of every edge of every mesh (B, V, 3)."""
        batch = vertices.shape[0]
        vectors = torch.sparse.mm(self.edge_matrix, _vertex_major(vertices))
        return vectors.view(-1, batch, 3).norm(dim=-1).transpose(0, 1)

    def edge_length_loss(self, vertices, reference_lengths):
        """Mean squared change of the edge lengths (metres^2) of (B, V, 3) vertices against
        `reference_lengths` (B, E) (edge_lengths of the reference meshes): zero under rigid motion."""
        return (self.edge_lengths(vertices) - reference_lengths).square().mean()

    def normal_consistency_loss(self, vertices):
        """Mean of 1 - cos(angle) between the normals of faces that share an edge, over every mesh."""
        rows = vertices.transpose(0, 1).contiguous()                               # (V, B, 3)
        v0, v1, v2 = (rows.index_select(0, self.faces[:, k]) for k in range(3))
        normals = F.normalize(torch.cross(v1 - v0, v2 - v0, dim=-1), dim=-1, eps=1e-12)
        return (1 - (normals.index_select(0, self.face_pairs[:, 0])
                     * normals.index_select(0, self.face_pairs[:, 1])).sum(-1)).mean()
