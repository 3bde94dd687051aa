"""The alignment's smaller silhouettes (FitProblem.alignment_view, problem.silhouette_view): masks
averaged over blocks, padded frames weighted 0 where the picture ends, and cameras whose render
at the smaller size is the block average of the full-size render (an independent check of the
pixel-centre convention: half a pixel off would show)."""
import numpy as np
import torch

from pipeline.fit.clip_data import ClipData
from pipeline.fit.problem import silhouette_view
from pipeline.render.antialias import edge_topology
from pipeline.render.renderer import RenderMesh, render
from render_meshes import icosphere, intrinsics


def _clip(masks, K):
    masks = torch.as_tensor(masks, dtype=torch.float64)[..., None]
    return ClipData(torch.zeros(*masks.shape[:3], 3, dtype=torch.float64), masks, K, info=None,
                    frames=np.arange(len(masks)))


def test_masks_are_block_averages_and_the_padding_says_nothing():
    generator = np.random.default_rng(0)
    masks = (generator.random((2, 7, 9)) > 0.5).astype(float)     # 7 x 9: padded to 8 x 10
    K = intrinsics(20.0, 9, 7).expand(2, 3, 3)
    view = silhouette_view(_clip(masks, K), None, 2)
    assert (view.height, view.width) == (4, 5)
    padded = np.zeros((2, 8, 10))
    padded[:, :7, :9] = masks
    expected = padded.reshape(2, 4, 2, 5, 2).mean(axis=(2, 4))
    assert np.allclose(view.masks[..., 0].numpy(), expected, atol=1e-12)
    inside = np.zeros((8, 10))
    inside[:7, :9] = 1
    assert np.allclose(view.weight[0, ..., 0].numpy(), inside.reshape(4, 2, 5, 2).mean(axis=(1, 3)), atol=1e-12)
    assert torch.allclose(view.K[0], torch.tensor([[10.0, 0, 2.25], [0, 10.0, 1.75], [0, 0, 1]], dtype=torch.float64))


def test_a_given_weight_is_averaged_and_factor_one_is_the_clip_itself():
    masks = np.ones((1, 4, 4))
    weight = torch.zeros(1, 4, 4, 1, dtype=torch.float64)
    weight[:, :2] = 1.0
    clip = _clip(masks, intrinsics(10.0, 4, 4)[None])
    view = silhouette_view(clip, weight, 2)
    assert np.allclose(view.weight[0, ..., 0].numpy(), [[1, 1], [0, 0]])
    assert silhouette_view(clip, None, 2).weight is None     # nothing padded, nothing weighed
    same = silhouette_view(clip, weight, 1)
    assert same.masks is clip.masks and same.weight is weight and same.K is clip.K


def _sphere_alpha(K, size):
    vertices, faces = icosphere(3)
    faces = torch.as_tensor(faces)
    points = torch.as_tensor(vertices)[None] * 0.3 + torch.tensor([0.05, -0.03, 2.0], dtype=torch.float64)
    return render(points, RenderMesh(faces, topology=edge_topology(faces)), K, size, size)["alpha"]


def test_the_smaller_camera_renders_the_block_average_of_the_full_render():
    size, factor = 96, 2
    K = intrinsics(120.0, size, size)[None]
    full = _sphere_alpha(K, size)
    view = silhouette_view(_clip(full[..., 0].detach(), K), None, factor)
    small = _sphere_alpha(view.K, view.height)
    error = (small - view.masks).abs().mean().item()
    shifted = view.K.clone()
    shifted[:, 0, 2] += 0.5       # the other pixel convention: half a small pixel to the side
    error_shifted = (_sphere_alpha(shifted, view.height) - view.masks).abs().mean().item()
    assert error < 0.001
    assert error_shifted > 10 * error


def test_a_fit_aligned_at_another_size_resumes_under_todays(tmp_path):
    """align_downscale changes no result that the rest of the fit depends on beyond rounding, so
    a checkpoint written under another (or before the setting: 1) resumes without the "other
    settings" refusal, and the finished fit's figures stand."""
    from pipeline.evaluate.exact_clips import write_clip
    from pipeline.fit import fitting
    from pipeline.fit.checkpoint import CHECKPOINT_FILE, load_checkpoint
    from pipeline.init import initialise_sequence
    from synth.motions import OPEN

    clip = tmp_path / "clip"
    write_clip(clip, OPEN, frames=3, size=64, turn_degrees=20)
    initialise_sequence(clip, "gt-noise", log=lambda *a: None)
    options = dict(progress="none", texture_size=64, batch_size=2, resolution=64, steps=(2, 2, 2), max_steps=3)
    first = fitting.fit(clip, tmp_path / "fit", align_downscale=1, **options)
    assert load_checkpoint(tmp_path / "fit" / CHECKPOINT_FILE, "cpu").settings.align_downscale == 1
    again = fitting.fit(clip, tmp_path / "fit", resume=True, **options)
    assert again["metrics"] == first["metrics"]
