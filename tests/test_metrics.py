"""Metrics against independent references (scikit-image SSIM, analytic cases)."""
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from skimage.metrics import structural_similarity

from pipeline import metrics


def images(seed=0, size=192):
    generator = torch.Generator().manual_seed(seed)
    a = torch.rand(1, size, size, 3, generator=generator, dtype=torch.float64)
    a = torch.nn.functional.avg_pool2d(a.permute(0, 3, 1, 2), 5, 1, 2).permute(0, 2, 3, 1)  # some structure
    b = (a + 0.05 * torch.randn(a.shape, generator=generator, dtype=torch.float64)).clamp(0, 1)
    return a, b


def test_ssim_matches_scikit_image():
    a, b = images()
    reference = structural_similarity(a[0].numpy(), b[0].numpy(), gaussian_weights=True, sigma=1.5,
                                      use_sample_covariance=False, data_range=1.0, channel_axis=2)
    # scikit-image averages over the image cropped by the window's half-width, as we do
    assert metrics.ssim(a, b).item() == pytest.approx(reference, abs=2e-3)


def test_ms_ssim_properties():
    a, b = images()
    assert metrics.ms_ssim(a, a).item() == pytest.approx(1.0)
    worse = (a + 0.15 * torch.randn(a.shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)).clamp(0, 1)
    assert 0 < metrics.ms_ssim(a, worse).item() < metrics.ms_ssim(a, b).item() < 1
    with pytest.raises(ValueError, match="at least"):
        metrics.ms_ssim(a[:, :64, :64], b[:, :64, :64])


def test_psnr_and_l1_analytic():
    a = torch.zeros(1, 8, 8, 3, dtype=torch.float64)
    b = a + 0.1
    assert metrics.psnr(a, b).item() == pytest.approx(20.0)
    assert metrics.l1(a, b).item() == pytest.approx(0.1)
    mask = torch.zeros(1, 8, 8, 1, dtype=torch.float64)
    mask[:, :2] = 1
    b[:, 2:] = 1.0  # errors outside the mask do not count
    assert metrics.psnr(a, b, mask).item() == pytest.approx(20.0)
    assert metrics.l1(a, b, mask).item() == pytest.approx(0.1)


def test_iou():
    a = torch.zeros(2, 4, 4, 1)
    b = torch.zeros(2, 4, 4, 1)
    a[0, :2], b[0, 1:3] = 1, 1          # 8 and 8 pixels overlapping in 4
    a[1], b[1] = 1, 1
    np.testing.assert_allclose(metrics.silhouette_iou(a, b).numpy(), [4 / 12, 1.0])


def test_procrustes_removes_similarity_transforms():
    rng = np.random.default_rng(0)
    target = torch.tensor(rng.normal(size=(21, 3)) * 0.05)
    moved = 1.3 * torch.tensor(Rotation.from_rotvec([0.4, -1.2, 2.0]).as_matrix()) @ target.T
    moved = moved.T + torch.tensor([0.1, -0.2, 0.5])
    assert metrics.procrustes_error(moved[None], target[None]).item() < 1e-12
    noisy = target + 0.001 * torch.tensor(rng.normal(size=(21, 3)))
    error = metrics.procrustes_error(noisy[None], target[None]).item()
    assert 0 < error < 0.002
    mirrored = target * torch.tensor([-1.0, 1.0, 1.0])  # a reflection is not a rotation
    assert metrics.procrustes_error(mirrored[None], target[None]).item() > 0.01


def test_mask_iou_of_known_overlaps():
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    a[:2] = True                          # 8 pixels
    b[1:3] = True                         # 8 pixels, 4 shared
    assert metrics.mask_iou(a, b) == pytest.approx(4 / 12)
    assert metrics.mask_iou(a, a) == 1.0 and metrics.mask_iou(a, ~a) == 0.0
    assert metrics.mask_iou(np.zeros((2, 2), bool), np.zeros((2, 2), bool)) == 0.0
