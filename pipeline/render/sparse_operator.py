"""A fixed sparse matrix applied to dense tensors with gradients: the renderer's normals and
tangents and the fit's surface regularisers are such products over a mesh's topology.

The matrix is stored twice, as CSR and its transpose as CSR, both built once: the backward pass of
A @ X is A^T @ G, which torch's own sparse product computes by transposing A at every call (about
2.5x the time of forward and backward with the transpose kept). Sparse CSR products run on the CPU
and on CUDA alike.
"""
from __future__ import annotations

import warnings

import torch


def _csr(rows, columns, values, shape, dtype, device):
    with warnings.catch_warnings():     # torch calls its CSR support "beta" at every construction, and
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        # torch 2.11 with CUDA says at the first construction that its invariant checks are off by default
        warnings.filterwarnings("ignore", message="Sparse invariant checks are implicitly disabled")
        matrix = torch.sparse_coo_tensor(torch.stack([rows, columns]), values, shape, check_invariants=True)
        return matrix.coalesce().to(dtype=dtype, device=device).to_sparse_csr()


def vertex_major(points):
    """(V, B * 3) a batch of B meshes' points (B, V, 3) laid out for a product over the vertices:
    each vertex's row holds it in every mesh."""
    return points.transpose(0, 1).reshape(points.shape[1], -1)


class SparseOperator:
    """The (shape) matrix with entries `values` at (rows, columns) (repeated entries summed), in
    `dtype` on `device`; `operator(X)` is the product with a dense (shape[1], N) X, differentiable
    in X."""

    def __init__(self, rows, columns, values, shape, dtype=torch.float32, device=None):
        values = torch.as_tensor(values, dtype=torch.float64, device=rows.device)
        self.shape = tuple(shape)
        self.matrix = _csr(rows, columns, values, self.shape, dtype, device)
        self.transposed = _csr(columns, rows, values, self.shape[::-1], dtype, device)

    def __call__(self, dense):
        return _SparseProduct.apply(dense, self)


class _SparseProduct(torch.autograd.Function):
    @staticmethod
    def forward(ctx, dense, operator):
        ctx.operator = operator
        return torch.sparse.mm(operator.matrix, dense)

    @staticmethod
    def backward(ctx, grad):
        return torch.sparse.mm(ctx.operator.transposed, grad.contiguous()), None
