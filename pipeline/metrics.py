"""Evaluation metrics: image quality (L1, PSNR, SSIM, MS-SSIM), silhouette IoU and
Procrustes-aligned 3D errors. Images are (B, H, W, C) tensors in [0, 1]."""
from __future__ import annotations

import torch
import torch.nn.functional as F

MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
_C1, _C2 = 0.01 ** 2, 0.03 ** 2  # for data range 1


def l1(a, b, mask=None):
    """Mean absolute difference, over the mask (B, H, W, 1) when given."""
    if mask is None:
        return (a - b).abs().mean()
    return ((a - b).abs() * mask).sum() / (mask.sum() * a.shape[-1]).clamp(min=1)


def psnr(a, b, mask=None):
    """Peak signal-to-noise ratio in dB for data range 1, over the mask when given."""
    if mask is None:
        mse = (a - b).square().mean()
    else:
        mse = ((a - b).square() * mask).sum() / (mask.sum() * a.shape[-1]).clamp(min=1)
    return 10 * torch.log10(1.0 / mse.clamp(min=1e-12))


def silhouette_iou(alpha, mask, threshold=0.5):
    """Intersection over union of binarised (B, H, W, 1) silhouettes, per frame (B,)."""
    a, b = alpha > threshold, mask > threshold
    union = (a | b).sum((1, 2, 3)).clamp(min=1)
    return (a & b).sum((1, 2, 3)).to(torch.float64) / union


def mask_iou(a, b) -> float:
    """Intersection over union of two boolean masks (numpy arrays of one shape); 0 for two empty ones."""
    return float((a & b).sum() / max((a | b).sum(), 1))


def _gaussian_window(size=11, sigma=1.5, dtype=torch.float64, device=None):
    x = torch.arange(size, dtype=dtype, device=device) - (size - 1) / 2
    g = torch.exp(-x * x / (2 * sigma * sigma))
    return g / g.sum()


def _ssim_components(x, y):
    """Mean SSIM and mean contrast-structure term of (B, C, H, W) images (valid windows)."""
    full, contrast_structure = _ssim_maps(x, y)
    return full.mean((1, 2, 3)), contrast_structure.mean((1, 2, 3))


def _ssim_maps(x, y):
    """SSIM and contrast-structure maps (B, C, H - 10, W - 10) of (B, C, H, W) images (valid windows)."""
    channels = x.shape[1]
    g = _gaussian_window(dtype=x.dtype, device=x.device)
    window_h = g.view(1, 1, 1, -1).expand(channels, 1, 1, -1)
    window_v = g.view(1, 1, -1, 1).expand(channels, 1, -1, 1)

    def blur(t):
        return F.conv2d(F.conv2d(t, window_h, groups=channels), window_v, groups=channels)

    mu_x, mu_y = blur(x), blur(y)
    sigma_x = blur(x * x) - mu_x ** 2
    sigma_y = blur(y * y) - mu_y ** 2
    sigma_xy = blur(x * y) - mu_x * mu_y
    contrast_structure = (2 * sigma_xy + _C2) / (sigma_x + sigma_y + _C2)
    luminance = (2 * mu_x * mu_y + _C1) / (mu_x ** 2 + mu_y ** 2 + _C1)
    return luminance * contrast_structure, contrast_structure


def ssim(a, b, mask=None):
    """Structural similarity (Gaussian window 11, sigma 1.5, data range 1) per frame (B,); with
    a mask (B, H, W, 1), the mean of the SSIM map over the windows centred inside it."""
    if mask is None:
        return _ssim_components(a.permute(0, 3, 1, 2), b.permute(0, 3, 1, 2))[0]
    full, _ = _ssim_maps(a.permute(0, 3, 1, 2), b.permute(0, 3, 1, 2))
    inside = mask.permute(0, 3, 1, 2)[..., 5:-5, 5:-5].to(full.dtype)
    return (full.mean(1, keepdim=True) * inside).sum((1, 2, 3)) / inside.sum((1, 2, 3)).clamp(min=1)


def ms_ssim(a, b):
    """Multi-scale SSIM (five scales, standard weights, data range 1) per frame (B,).
    Images must be at least 161 pixels on their short side."""
    x, y = a.permute(0, 3, 1, 2), b.permute(0, 3, 1, 2)
    if min(x.shape[-2:]) < 11 * 2 ** 4:
        raise ValueError(f"MS-SSIM needs images of at least 176 pixels, got {tuple(x.shape[-2:])}")
    weights = torch.tensor(MS_SSIM_WEIGHTS, dtype=x.dtype, device=x.device)
    factors = []
    for scale in range(len(MS_SSIM_WEIGHTS)):
        full, contrast_structure = _ssim_components(x, y)
        if scale == len(MS_SSIM_WEIGHTS) - 1:
            factors.append(full.clamp(min=1e-12))
        else:
            factors.append(contrast_structure.clamp(min=1e-12))
            x, y = F.avg_pool2d(x, 2), F.avg_pool2d(y, 2)
    return torch.prod(torch.stack(factors, dim=1) ** weights, dim=1)


def procrustes_align(prediction, target):
    """Similarity transform (scale, rotation, translation) of `prediction` (N, 3) that best fits
    `target` (N, 3) in least squares (Umeyama); returns the aligned prediction."""
    mu_p, mu_t = prediction.mean(0), target.mean(0)
    p, t = prediction - mu_p, target - mu_t
    covariance = t.T @ p / len(p)
    u, s, vh = torch.linalg.svd(covariance)
    d = torch.ones(3, dtype=prediction.dtype, device=prediction.device)
    d[2] = torch.sign(torch.linalg.det(u @ vh))
    rotation = u @ torch.diag(d) @ vh
    scale = (s * d).sum() / p.square().sum(-1).mean()
    return scale * p @ rotation.T + mu_t


def procrustes_error(prediction, target):
    """Mean per-point distance after Procrustes alignment, per frame: (B, N, 3) -> (B,)."""
    return torch.stack([(procrustes_align(p, t) - t).norm(dim=-1).mean() for p, t in zip(prediction, target)])
