"""synth/render.py end to end: exact ground truth against the torch model and Blender's own
evaluation, keypoints against the projection and the masks, masks against an independent
rasterisation, both invocations alike, and one-line errors. Tiny renders only."""
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.formats import camera
from pipeline.formats import sequence_folder as seq
from pipeline.handmodel.lbs import HandModel, load_model_data
from pipeline.render.renderer import RenderMesh, render

bpy = pytest.importorskip("bpy")

from synth import SynthError  # noqa: E402
from synth.clip import make_person, render_clip  # noqa: E402
from synth.options import parse_clip_args  # noqa: E402
from synth.passes import make_mask_scene, render_still  # noqa: E402
from harp_addon.rig import build_hand_rig  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
RENDER = ROOT / "synth" / "render.py"
CLI_ARGS = ["--preview", "--mode", "hand", "--side", "left", "--motion", "random", "--identity", "3",
            "--seed", "5", "--lighting", "sun", "--background", "procedural"]
BLENDER_STYLE = ("import runpy, sys; script = sys.argv[1]; "
                 "sys.argv = ['blender', '-b', '--factory-startup', '-P', script, '--'] + sys.argv[2:]; "
                 "runpy.run_path(script, run_name='__main__')")
TIPS = [4, 8, 12, 16, 20]
MM = 1e-3


def run_cli(args, blender_style=False, cwd=ROOT):
    command = [sys.executable, "-c", BLENDER_STYLE, str(RENDER)] if blender_style else [sys.executable, str(RENDER)]
    return subprocess.run(command + [str(a) for a in args], capture_output=True, text=True, cwd=cwd, timeout=300)


def posed_model(gt, offsets=None):
    """Torch reference: the saved parameters posed by HandModel (optionally with the personal
    displacements added to the rest template). Returns vertices (F, V, 3), keypoints (F, K, 3)."""
    data = load_model_data(gt.mode, gt.side)
    if offsets is not None:
        data = dataclasses.replace(data, vertices=data.vertices + offsets)
    out = HandModel(data, dtype=torch.float64)(torch.as_tensor(gt.betas), torch.as_tensor(gt.pose),
                                                torch.as_tensor(gt.global_orient), torch.as_tensor(gt.transl))
    return out.vertices.numpy(), out.keypoints.numpy()


def silhouette(vertices, faces, K, width, height):
    """Independent rasteriser: pixels whose centre lies inside a projected triangle."""
    pixels, _ = camera.project(vertices, K)
    mask = np.zeros((height, width), bool)
    for a, b, c in pixels[faces]:
        lo = np.floor(np.minimum(np.minimum(a, b), c) - 0.5).astype(int).clip(0, [width - 1, height - 1])
        hi = np.ceil(np.maximum(np.maximum(a, b), c) - 0.5).astype(int).clip(0, [width - 1, height - 1])
        x, y = np.meshgrid(np.arange(lo[0], hi[0] + 1) + 0.5, np.arange(lo[1], hi[1] + 1) + 0.5)
        d1 = (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])
        d2 = (c[0] - b[0]) * (y - b[1]) - (c[1] - b[1]) * (x - b[0])
        d3 = (a[0] - c[0]) * (y - c[1]) - (a[1] - c[1]) * (x - c[0])
        inside = ((d1 >= 0) & (d2 >= 0) & (d3 >= 0)) | ((d1 <= 0) & (d2 <= 0) & (d3 <= 0))
        mask[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] |= inside
    return mask


def iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def distance_to_mask(points, mask):
    """Pixel distance from each (N, 2) point to the nearest mask pixel centre."""
    rows, cols = np.nonzero(mask)
    centres = np.stack([cols + 0.5, rows + 0.5], axis=1)
    return np.array([np.linalg.norm(centres - p, axis=1).min() for p in points])


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """An in-process clip: 128x128, 4 frames, hand + forearm, random motion, three lights."""
    out = tmp_path_factory.mktemp("clip")
    settings = parse_clip_args(["--out", out, "--overwrite", "--width", 128, "--height", 128, "--frames", 4,
                                "--samples", 1, "--texture-size", 128, "--motion", "random", "--mode", "arm",
                                "--identity", 1, "--seed", 2, "--lighting", "three", "--azimuth", 30,
                                "--elevation", 10])
    render_clip(settings, log=lambda message: None)
    info = seq.validate_sequence_folder(out)
    return settings, info, seq.read_ground_truth(out / seq.GT_FILE)


@pytest.fixture(scope="module")
def cli_runs(tmp_path_factory):
    """The same preview rendered as `python synth/render.py` and as `blender -b -P ... --` would."""
    base = tmp_path_factory.mktemp("cli")
    python_run = run_cli(["--out", base / "python", *CLI_ARGS])
    blender_run = run_cli(["--out", base / "blender", *CLI_ARGS], blender_style=True, cwd=base)
    assert python_run.returncode == 0, python_run.stderr
    assert blender_run.returncode == 0, blender_run.stderr
    return base / "python", base / "blender"


def test_ground_truth_equals_the_torch_model(clip):
    """Before the personal displacements, Blender's evaluated rig posed with the saved
    parameters is the torch model (< 0.1 mm), frame by frame; so are the keypoints."""
    settings, info, gt = clip
    person = make_person(settings, with_appearance=False)
    collection = bpy.data.collections.new("check")
    bpy.context.scene.collection.children.link(collection)
    rig = build_hand_rig(person.data, person.identity.betas, person.offsets, collection=collection, name="check")
    reference, keypoints = posed_model(gt)
    for frame in range(gt.frame_count):
        rig.set_pose(gt.pose[frame], gt.global_orient[frame], gt.transl[frame])
        blender = rig.evaluated_vertices(personal=False)
        assert np.abs(blender - reference[frame]).max() < 0.1 * MM
    np.testing.assert_allclose(gt.keypoints3d, keypoints[:, :21], atol=0.1 * MM)
    np.testing.assert_allclose(gt.personal_offsets, person.offsets, atol=1e-7)


def test_rendered_surface_is_the_model_plus_personal_displacements(clip):
    _, _, gt = clip
    reference, _ = posed_model(gt, gt.personal_offsets.astype(np.float64))
    assert np.abs(gt.vertices - reference).max() < 0.1 * MM
    # and the personal displacements are really there (a few millimetres)
    plain, _ = posed_model(gt)
    assert 0.5 * MM < np.linalg.norm(gt.vertices - plain, axis=2).max() < 5 * MM


def test_keypoints_project_into_the_masks(clip):
    settings, info, gt = clip
    pixels, depth = camera.project(gt.keypoints3d.reshape(-1, 3), info.K)
    np.testing.assert_allclose(gt.keypoints2d.reshape(-1, 2), pixels, atol=1e-9)
    assert (depth > 0).all()
    for frame in range(gt.frame_count):
        mask = seq.read_mask(seq.mask_path(settings.out, info, frame))
        distance = distance_to_mask(gt.keypoints2d[frame], mask)
        assert distance[TIPS].max() <= 2.0, distance
        assert np.delete(distance, TIPS).max() <= 0.75, distance


def test_masks_are_binary_and_match_an_independent_rasterisation_and_our_renderer(clip):
    settings, info, gt = clip
    faces = load_model_data(gt.mode, gt.side).faces
    for frame in range(gt.frame_count):
        stored = seq.read_rgb(seq.mask_path(settings.out, info, frame))
        assert set(np.unique(stored)) <= {0, 255}
        mask = stored[..., 0] == 255
        ours = silhouette(gt.vertices[frame].astype(np.float64), faces, info.K, info.width, info.height)
        assert iou(mask, ours) >= 0.99, iou(mask, ours)
        assert 0.02 < mask.mean() < 0.9
        # and the pipeline's own renderer, through its camera convention
        rendered = render(torch.as_tensor(gt.vertices[frame:frame + 1], dtype=torch.float64),
                          RenderMesh(torch.as_tensor(faces, dtype=torch.long)), torch.as_tensor(info.K),
                          info.height, info.width, outputs=("alpha",), antialiased=False)["alpha"]
        assert iou(mask, rendered[0, ..., 0].numpy() > 0.5) >= 0.99


def test_cycles_mask_engine_agrees_with_workbench(clip, tmp_path):
    settings, info, gt = clip
    scene = bpy.data.scenes["Scene"]
    other = make_mask_scene(scene, bpy.data.collections["hand"], scene.camera, "cycles")
    render_still(other, tmp_path / "cycles.png")
    cycles_mask = seq.read_rgb(tmp_path / "cycles.png")
    assert set(np.unique(cycles_mask)) <= {0, 255}
    workbench = seq.read_mask(seq.mask_path(settings.out, info, gt.frame_count - 1))
    assert iou(cycles_mask[..., 0] == 255, workbench) >= 0.99


def test_both_invocations_write_identical_ground_truth(cli_runs):
    python_out, blender_out = cli_runs
    a, b = seq.read_ground_truth(python_out / seq.GT_FILE), seq.read_ground_truth(blender_out / seq.GT_FILE)
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y, err_msg=field.name)
        else:
            assert x == y, field.name
    assert (python_out / seq.GT_ALBEDO_FILE).read_bytes() == (blender_out / seq.GT_ALBEDO_FILE).read_bytes()
    info_a, info_b = seq.validate_sequence_folder(python_out), seq.validate_sequence_folder(blender_out)
    np.testing.assert_array_equal(info_a.K, info_b.K)
    for frame in range(info_a.frame_count):
        np.testing.assert_array_equal(seq.read_rgb(seq.mask_path(python_out, info_a, frame)),
                                      seq.read_rgb(seq.mask_path(blender_out, info_b, frame)))


def test_cli_preview_is_a_valid_left_hand_clip(cli_runs):
    out = cli_runs[0]
    info = seq.validate_sequence_folder(out)
    gt = seq.read_ground_truth(out / seq.GT_FILE)
    assert (info.width, info.height, info.frame_count, info.hand_side) == (64, 64, 4, "left")
    assert gt.mode == "hand" and gt.vertices.shape == (4, load_model_data("hand").num_vertices, 3)
    reference, keypoints = posed_model(gt, gt.personal_offsets.astype(np.float64))
    assert np.abs(gt.vertices - reference).max() < 0.1 * MM
    assert gt.light["preset"] == "sun" and len(gt.light["lights"]) == 1
    metadata = json.loads((out / seq.SEQUENCE_FILE).read_text())["metadata"]
    assert metadata["settings"]["motion"] == "random" and metadata["timing_s"]["total"] < 60


def one_line_error(result):
    lines = result.stderr.strip().splitlines()
    assert result.returncode != 0
    assert len(lines) == 1, result.stderr
    return lines[0]


def test_cli_errors(tmp_path):
    unknown = run_cli(["--out", tmp_path / "a", "--colour", "red"])
    assert unknown.returncode == 2 and "usage:" in unknown.stderr and "--colour" in unknown.stderr
    missing = one_line_error(run_cli(["--out", tmp_path / "b", "--preview", "--model-folder", tmp_path / "nowhere"]))
    assert "hand model file not found" in missing
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "old.txt").write_text("x")
    assert "is not empty" in one_line_error(run_cli(["--out", tmp_path / "c", "--preview"]))
    assert "--fov" in one_line_error(run_cli(["--out", tmp_path / "d", "--fov", "0"]))
    assert not (tmp_path / "d").exists()  # nothing written for impossible settings


@pytest.mark.parametrize("args, message", [
    (["--focal", "100", "--fov", "30"], "either --focal or --fov"),
    (["--elevation", "90"], "--elevation"),
    (["--skin-tone", "1.5"], "--skin-tone"),
    (["--subsurface", "1.5"], "--subsurface"),
    (["--specular-level", "-0.1"], "--specular-level"),
    (["--frames", "0"], "--frames"),
    (["--seconds", "0.01"], "less than one frame"),
    (["--width", "4"], "image size"),
    (["--betas", "1,2"], "needs 12 values"),
    (["--features", "tattoo,wings"], "unknown feature 'wings'"),
    (["--texture-size", "500"], "power of two"),
    (["--distance", "0.01"], "--distance"),
])
def test_impossible_settings(tmp_path, args, message):
    with pytest.raises(SynthError, match=message) as error:
        parse_clip_args(["--out", tmp_path / "x", *args])
    assert "\n" not in str(error.value)


def test_blender_renders_with_the_saved_albedo_and_the_roughness_map(clip):
    settings, info, gt = clip
    material = bpy.data.materials["skin"]
    images = {node.image.name: node.image for node in material.node_tree.nodes if node.type == "TEX_IMAGE"}
    albedo = next(image for image in images.values() if not image.name.endswith("roughness"))
    width, height = albedo.size
    pixels = np.empty(width * height * 4, dtype=np.float32)
    albedo.pixels.foreach_get(pixels)
    stored = seq.read_rgb(settings.out / seq.GT_ALBEDO_FILE)
    np.testing.assert_array_equal(np.round(pixels.reshape(height, width, 4)[::-1, :, :3] * 255), stored)
    roughness = images["skin_roughness"]
    values = np.empty(roughness.size[0] * roughness.size[1] * 4, dtype=np.float32)
    roughness.pixels.foreach_get(values)
    assert 0.3 < values.reshape(-1, 4)[:, 0].mean() < 0.7


def test_the_room_light_is_cool_on_the_left_warm_on_the_right_and_bright_above(tmp_path):
    """`--lighting room`'s environment (its window switched off): a grey diffuse sphere in front
    of the camera is bluer on its left (-x) than on its right, and brighter above (-y) than below."""
    from synth.clip import new_scene
    from synth.lighting import setup_lighting

    settings = parse_clip_args(["--out", str(tmp_path), "--width", "64", "--height", "64", "--samples", "32"])
    K = camera.intrinsics_from_fov(64, 64, 30.0)
    scene = new_scene(settings, K)
    description = setup_lighting(scene, "room", "plain", target=[0.0, 0.0, 1.0])
    assert description["ambient"]["colour"] == "room" and description["lights"][0]["type"] == "area"
    bpy.data.objects["window"].data.energy = 0.0
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.2, location=(0.0, 0.0, 1.0), segments=48, ring_count=24)
    sphere = bpy.context.active_object
    material = bpy.data.materials.new("grey")
    if not material.node_tree:      # before Blender 5.0 a new material has none until use_nodes is set
        material.use_nodes = True
    material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    material.node_tree.nodes["Principled BSDF"].inputs["Roughness"].default_value = 1.0
    sphere.data.materials.append(material)
    render_still(scene, tmp_path / "sphere.png")
    image = ((seq.read_rgb(tmp_path / "sphere.png") / 255.0 + 0.055) / 1.055) ** 2.4    # sRGB -> linear
    left, right = image[24:40, 18:28].reshape(-1, 3).mean(0), image[24:40, 36:46].reshape(-1, 3).mean(0)
    top, bottom = image[18:28, 24:40].reshape(-1, 3).mean(0), image[36:46, 24:40].reshape(-1, 3).mean(0)
    # a diffuse surface averages the light over its hemisphere, so the sphere's sides differ far
    # less than the room's ends (measured 1.34x and 1.24x); uniform white light gives 1 and 1
    assert left[2] / left[0] > 1.2 * right[2] / right[0], (left, right)
    assert top.sum() > 1.12 * bottom.sum(), (top, bottom)


def test_dataset_rendered_by_two_workers_matches_one_render_at_a_time(tmp_path):
    """synth/dataset.py --jobs 2: the clips rendered in two processes, Cycles' threads shared out,
    are the clips rendered one at a time (ground truth exactly, pixels within Cycles' noise)."""
    import cv2

    from synth import dataset

    subset = ["--identities", "medium-light", "--motions", "flip,fingers", "--views", "front", "--preview"]
    assert dataset.main(["dataset.py", "--out", str(tmp_path / "one"), *subset]) == 0
    assert dataset.main(["dataset.py", "--out", str(tmp_path / "two"), "--jobs", "2", *subset]) == 0
    names = sorted(p.name for p in (tmp_path / "one").iterdir() if (p / "sequence.json").is_file())
    assert len(names) == 2 and names == sorted(p.name for p in (tmp_path / "two").iterdir()
                                               if (p / "sequence.json").is_file())
    index = json.loads((tmp_path / "two" / "dataset.json").read_text())
    assert sorted(index["clips"]) == names and all("--threads" not in c["args"] for c in index["clips"].values())
    for name in names:
        one, two = np.load(tmp_path / "one" / name / "gt.npz"), np.load(tmp_path / "two" / name / "gt.npz")
        assert np.array_equal(one["keypoints3d"], two["keypoints3d"])
        for frame in sorted((tmp_path / "one" / name / "rgb").iterdir()):
            a = cv2.imread(str(frame)).astype(float)
            b = cv2.imread(str(tmp_path / "two" / name / "rgb" / frame.name)).astype(float)
            assert np.abs(a - b).mean() < 2.0, (name, frame.name)
