"""The perceptual term: VGG16 features when the user has the weights, otherwise a weight-free
Laplacian-pyramid L1 (multi-scale band-pass differences) that needs no download.

VGG16 weights are never fetched: put torchvision's ImageNet VGG16 state dict (or just its
`features.*` part) at $HARP_VGG16_WEIGHTS or ~/.cache/harp/vgg16.pth. The loss compares
masked images with L1 over pixels (x1), relu1_2 (x1/16), relu2_2 (x1/8), relu3_3 (x1/4) and
relu4_3 (x1), as the reference implementation does.
"""
from __future__ import annotations

import os
from pathlib import Path

import torch
import torch.nn as nn
import torch.nn.functional as F

VGG_LAYER_WEIGHTS = {3: 1 / 16, 8: 1 / 8, 15: 1 / 4, 22: 1.0}  # relu1_2, relu2_2, relu3_3, relu4_3
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
_VGG16_LAYOUT = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512]


class PerceptualWeightsError(ValueError):
    """VGG16 weights are missing or do not fit the network."""


class Vgg16Features(nn.Module):
    """torchvision's vgg16().features up to relu4_3 (same layer indices and parameter names)."""

    def __init__(self):
        super().__init__()
        layers, channels = [], 3
        for item in _VGG16_LAYOUT:
            if item == "M":
                layers.append(nn.MaxPool2d(2, 2))
            else:
                layers += [nn.Conv2d(channels, item, 3, padding=1), nn.ReLU(inplace=False)]
                channels = item
        self.features = nn.Sequential(*layers)
        self.requires_grad_(False)

    def forward(self, image):
        """image (B, 3, H, W) in [0, 1] -> {layer index: activations} for VGG_LAYER_WEIGHTS."""
        mean = image.new_tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
        std = image.new_tensor(IMAGENET_STD).view(1, 3, 1, 1)
        x = (image - mean) / std
        outputs = {}
        for index, layer in enumerate(self.features):
            x = layer(x)
            if index in VGG_LAYER_WEIGHTS:
                outputs[index] = x
        return outputs


def default_weights_path():
    return Path(os.environ.get("HARP_VGG16_WEIGHTS", Path.home() / ".cache" / "harp" / "vgg16.pth"))


def load_vgg16(path=None, device=None):
    """Vgg16Features with weights from a local state-dict file (torchvision key names, with or
    without the `features.` prefix; classifier weights are ignored)."""
    path = Path(path) if path else default_weights_path()
    if not path.is_file():
        raise PerceptualWeightsError(f"VGG16 weights not found at {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:
        raise PerceptualWeightsError(f"cannot read VGG16 weights {path}: {error}") from None
    if isinstance(state, dict) and "state_dict" in state:
        state = state["state_dict"]
    features = {}
    for key, value in state.items():
        name = key[len("features."):] if key.startswith("features.") else key
        if name.split(".")[0].isdigit():
            features[name] = value
    model = Vgg16Features()
    wanted = model.features.state_dict()
    missing = [k for k in wanted if k not in features]
    if missing:
        raise PerceptualWeightsError(f"{path} lacks VGG16 feature weights such as {missing[0]}")
    for key, value in wanted.items():
        if features[key].shape != value.shape:
            raise PerceptualWeightsError(f"{path}: {key} has shape {tuple(features[key].shape)}, "
                                         f"expected {tuple(value.shape)}")
    model.features.load_state_dict({k: features[k] for k in wanted})
    return model.to(device).eval()


def vgg_loss(rendered, image, mask, network: Vgg16Features):
    """The reference perceptual term on (B, H, W, 3) images masked by (B, H, W, 1)."""
    a = (rendered * mask).permute(0, 3, 1, 2)
    b = (image * mask).permute(0, 3, 1, 2)
    loss = (a - b).abs().mean()
    features_a, features_b = network(a), network(b)
    for index, weight in VGG_LAYER_WEIGHTS.items():
        loss = loss + weight * (features_a[index] - features_b[index]).abs().mean()
    return loss


def _blur_down(x):
    """The 5x5 binomial blur at every other pixel (stride 2: the pixels kept, and only those)."""
    kernel = x.new_tensor([1.0, 4.0, 6.0, 4.0, 1.0]) / 16
    kernel = (kernel[:, None] * kernel[None, :]).expand(x.shape[1], 1, 5, 5)
    return F.conv2d(F.pad(x, (2, 2, 2, 2), mode="replicate"), kernel, groups=x.shape[1], stride=2)


def laplacian_pyramid(x, levels):
    """Band-pass levels (finest first) and the low-pass residual of (B, C, H, W) images."""
    bands = []
    for _ in range(levels):
        if min(x.shape[-2:]) < 4:
            break
        low = _blur_down(x)
        up = F.interpolate(low, size=x.shape[-2:], mode="bilinear", align_corners=False)
        bands.append(x - up)
        x = low
    return bands + [x]


def laplacian_pyramid_loss(rendered, image, mask, levels=5):
    """Weight-free perceptual term: mean L1 between the Laplacian pyramids of the masked images
    (B, H, W, 3), every band weighted alike so that fine detail counts as much as colour.
    The pyramid is linear (blur, subsample, upsample, replicated borders), so the pyramid of the
    difference is the difference of the pyramids: one pyramid, not two (the term took about
    40% less time on `full`)."""
    bands = laplacian_pyramid(((rendered - image) * mask).permute(0, 3, 1, 2), levels)
    return sum(band.abs().mean() for band in bands) / len(bands)


def perceptual_term(weights_path=None, device=None):
    """(name, loss function(rendered, image, mask)): VGG16 if its weights are available locally
    (or `weights_path` is given), else the Laplacian pyramid."""
    path = Path(weights_path) if weights_path else default_weights_path()
    if weights_path or path.is_file():
        network = load_vgg16(path, device)
        return "vgg16", lambda rendered, image, mask: vgg_loss(rendered, image, mask, network)
    return "laplacian_pyramid", laplacian_pyramid_loss
