"""The component-wise cross product and the hand-written unit vectors against torch's own, and
their gradients against finite differences (zero vectors included)."""
import torch

from pipeline.render.vector_ops import cross3, normalized


def test_cross_and_unit_vectors_are_torchs():
    generator = torch.Generator().manual_seed(2)
    u, v = torch.randn(2, 50, 4, 3, generator=generator, dtype=torch.float64)
    u[0, 0] = 0.0                                  # a zero vector: its unit is 0, as F.normalize's
    assert torch.allclose(cross3(u, v), torch.cross(u, v, dim=-1), atol=1e-15, rtol=0)
    weights = torch.randn(50, 4, 3, generator=generator, dtype=torch.float64)
    grads = []
    for unit in (normalized, lambda x: torch.nn.functional.normalize(x, dim=-1, eps=1e-12)):
        leaf = u.clone().requires_grad_(True)
        value = unit(leaf)
        (value * weights).sum().backward()
        grads.append((value.detach(), leaf.grad))
    assert torch.allclose(grads[0][0], grads[1][0], atol=1e-15, rtol=0)
    assert torch.allclose(grads[0][1], grads[1][1], atol=1e-12, rtol=0)
    assert torch.equal(grads[0][0][0, 0], torch.zeros(3, dtype=torch.float64))


def test_their_gradients_match_finite_differences():
    generator = torch.Generator().manual_seed(3)
    u, v = (value.requires_grad_(True) for value in torch.randn(2, 6, 3, generator=generator, dtype=torch.float64))
    assert torch.autograd.gradcheck(cross3, (u, v))
    assert torch.autograd.gradcheck(lambda x: normalized(x), (u,))
    assert torch.autograd.gradcheck(lambda x, y: normalized(cross3(x, y)), (u, v))
