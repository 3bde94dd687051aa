"""Perceptual terms: the VGG16 loader on weights we make, and the weight-free default."""
import pytest
import torch

from pipeline.fit import perceptual


def test_vgg16_loader_reads_torchvision_style_weights(tmp_path):
    source = perceptual.Vgg16Features()
    torch.manual_seed(0)
    for parameter in source.parameters():
        parameter.data.normal_(0, 0.05)
    state = {f"features.{k}": v for k, v in source.features.state_dict().items()}
    state["classifier.0.weight"] = torch.zeros(4, 4)  # a full torchvision checkpoint has these
    path = tmp_path / "vgg16.pth"
    torch.save(state, path)
    loaded = perceptual.load_vgg16(path)
    for (name, a), (_, b) in zip(source.features.state_dict().items(), loaded.features.state_dict().items()):
        assert torch.equal(a, b), name
    image = torch.rand(1, 32, 32, 3)
    mask = torch.ones(1, 32, 32, 1)
    assert perceptual.vgg_loss(image, image, mask, loaded).item() == 0.0
    other = image.clone()
    other[:, 10:20, 10:20] = 1 - other[:, 10:20, 10:20]
    value = perceptual.vgg_loss(other.requires_grad_(True), image, mask, loaded)
    value.backward()
    assert value.item() > 0 and torch.isfinite(other.grad).all()
    name, function = perceptual.perceptual_term(path)
    assert name == "vgg16" and function(image, image, mask).item() == 0.0


def test_missing_or_wrong_weights_give_clear_errors(tmp_path, monkeypatch):
    with pytest.raises(perceptual.PerceptualWeightsError, match="not found"):
        perceptual.load_vgg16(tmp_path / "none.pth")
    bad = tmp_path / "bad.pth"
    torch.save({"features.0.weight": torch.zeros(1)}, bad)
    with pytest.raises(perceptual.PerceptualWeightsError, match="shape|lacks"):
        perceptual.load_vgg16(bad)
    monkeypatch.setenv("HARP_VGG16_WEIGHTS", str(tmp_path / "absent.pth"))
    name, _ = perceptual.perceptual_term()
    assert name == "laplacian_pyramid"


def test_laplacian_pyramid_loss_weighs_structure_over_brightness():
    """A blur and a uniform brightening with the same L1 error: the pyramid penalises the lost
    detail more than the brightness change. The pyramid also reconstructs the image exactly."""
    ys, xs = torch.meshgrid(torch.arange(64), torch.arange(64), indexing="ij")
    sharp = 0.25 + 0.5 * (((ys // 6) + (xs // 6)) % 2).float()[None, :, :, None].expand(1, 64, 64, 3)
    kernel = torch.ones(3, 1, 5, 5) / 25
    padded = torch.nn.functional.pad(sharp.permute(0, 3, 1, 2), (2, 2, 2, 2), mode="replicate")
    blurred = torch.nn.functional.conv2d(padded, kernel, groups=3).permute(0, 2, 3, 1)
    mask = torch.ones(1, 64, 64, 1)
    l1_blur = (blurred - sharp).abs().mean()
    brighter = sharp + l1_blur
    assert (brighter - sharp).abs().mean() == pytest.approx(l1_blur.item())
    assert perceptual.laplacian_pyramid_loss(blurred, sharp, mask) > 1.25 * perceptual.laplacian_pyramid_loss(brighter, sharp, mask)
    assert perceptual.laplacian_pyramid_loss(sharp, sharp, mask) == 0
    levels = perceptual.laplacian_pyramid(sharp.permute(0, 3, 1, 2), 4)
    rebuilt = levels[-1]
    for band in reversed(levels[:-1]):
        rebuilt = torch.nn.functional.interpolate(rebuilt, size=band.shape[-2:], mode="bilinear", align_corners=False) + band
    assert torch.allclose(rebuilt, sharp.permute(0, 3, 1, 2), atol=1e-6)


def test_laplacian_pyramid_loss_is_the_l1_between_two_pyramids():
    """The loss takes one pyramid of the masked difference; by the pyramid's linearity that is
    the L1 between the pyramids of the two masked images (its definition), values and gradients."""
    generator = torch.Generator().manual_seed(3)
    rendered = torch.rand(2, 37, 45, 3, generator=generator, dtype=torch.float64, requires_grad=True)
    image = torch.rand(2, 37, 45, 3, generator=generator, dtype=torch.float64)
    mask = (torch.rand(2, 37, 45, 1, generator=generator) > 0.3).double()

    def two_pyramids(a, b):
        pa = perceptual.laplacian_pyramid((a * mask).permute(0, 3, 1, 2), 5)
        pb = perceptual.laplacian_pyramid((b * mask).permute(0, 3, 1, 2), 5)
        return sum((x - y).abs().mean() for x, y in zip(pa, pb)) / len(pa)

    fused = perceptual.laplacian_pyramid_loss(rendered, image, mask)
    definition = two_pyramids(rendered, image)
    assert fused.item() == pytest.approx(definition.item(), rel=1e-12)
    grad_fused, = torch.autograd.grad(fused, rendered)
    grad_definition, = torch.autograd.grad(definition, rendered)
    assert torch.allclose(grad_fused, grad_definition, atol=1e-12)


def test_pyramid_blur_is_the_binomial_blur_at_every_other_pixel():
    """Against the separable binomial filter written out, on odd and even sizes: replicated
    borders, the even pixels kept."""
    generator = torch.Generator().manual_seed(1)
    for height, width in [(9, 12), (16, 7)]:
        x = torch.rand(2, 3, height, width, generator=generator, dtype=torch.float64)
        taps = torch.tensor([1.0, 4.0, 6.0, 4.0, 1.0], dtype=torch.float64) / 16
        padded = torch.nn.functional.pad(x, (2, 2, 2, 2), mode="replicate")
        rows = sum(taps[k] * padded[..., k:k + height, :] for k in range(5))
        blurred = sum(taps[k] * rows[..., :, k:k + width] for k in range(5))
        assert torch.allclose(perceptual._blur_down(x), blurred[..., ::2, ::2], atol=1e-12)
