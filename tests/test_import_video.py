"""`harp import-video`: crop, resize and intrinsics against projections, and one-line errors."""
import cv2
import numpy as np
import pytest

from pipeline import sequence_import as si
from pipeline.cli import main
from pipeline.formats import sequence_folder as seq
from pipeline.formats.camera import project

WIDTH, HEIGHT = 320, 240
K_SOURCE = np.array([[300.0, 0, 170.0], [0, 300.0, 115.0], [0, 0, 1]])


def disc_points(frames):
    """Camera-frame centres (F, 3) of a 'hand' (a sphere) moving across the view, metres."""
    t = np.linspace(0, 1, frames)
    return np.stack([-0.05 + 0.08 * t, 0.02 * np.sin(6 * t), np.full(frames, 0.6)], axis=1)


def draw_clip(folder, frames=6, centres=None, radius_px=25, video=False, masks_as_video=False):
    """Frames (RGB noise + a bright disc) and masks (the disc) at the projections of
    disc_points through K_SOURCE; returns (frame source, mask source, pixel centres (F, 2))."""
    folder.mkdir(parents=True, exist_ok=True)
    pixels = project(disc_points(frames), K_SOURCE)[0] if centres is None else np.asarray(centres, float)
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH] + 0.5
    images, masks = [], []
    for u, v in pixels:
        inside = (cols - u) ** 2 + (rows - v) ** 2 <= radius_px ** 2
        image = rng.integers(0, 80, (HEIGHT, WIDTH, 3)).astype(np.uint8)
        image[inside] = (230, 180, 160)
        images.append(image)
        masks.append(np.where(inside, 255, 0).astype(np.uint8))
    return _store(folder, "frames", images, video), _store(folder, "masks", masks, masks_as_video), pixels


def _store(folder, name, images, video):
    if video:
        path = folder / f"{name}.avi"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25, (WIDTH, HEIGHT))
        for image in images:
            writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image[..., ::-1].copy())
        writer.release()
        return path
    (folder / name).mkdir(exist_ok=True)
    for index, image in enumerate(images):
        cv2.imwrite(str(folder / name / f"{index}.png"), image if image.ndim == 2 else image[..., ::-1])
    return folder / name


def run(capsys, *args):
    code = main(["import-video", *[str(a) for a in args]])
    captured = capsys.readouterr()
    return code, captured.out, captured.err.strip().splitlines()


def mask_centroids(out, info):
    centres = []
    for index in range(info.frame_count):
        rows, cols = np.nonzero(seq.read_mask(seq.mask_path(out, info, index)))
        centres.append([cols.mean() + 0.5, rows.mean() + 0.5])
    return np.array(centres)


def test_crop_keeps_the_intrinsics_consistent(tmp_path, capsys):
    frames, masks, _ = draw_clip(tmp_path / "src")
    out = tmp_path / "seq"
    code, stdout, _ = run(capsys, frames, "--masks", masks, "--out", out, "--size", 96, "--side", "right",
                          "--K", "300,300,170,115", "--crop", "clip")
    assert code == 0 and "wrote 6 frames" in stdout
    info = seq.validate_sequence_folder(out)
    assert (info.width, info.height, info.frame_count, info.hand_side) == (96, 96, 6, "right")
    assert info.principal_points is None
    # the disc's centre, projected with the new K, is where the imported mask's centroid is
    expected = project(disc_points(6), info.K)[0]
    np.testing.assert_allclose(mask_centroids(out, info), expected, atol=0.35)
    # and the crop is square around the union of the masks with the margin
    crop = info.metadata["crop"]
    union_width = (expected[:, 0].max() - expected[:, 0].min()) * crop["side"] / 96 + 50
    assert crop["side"] == pytest.approx(union_width * 1.3, abs=2)
    rgb = seq.read_rgb(seq.frame_path(out, info, 0))
    assert rgb.shape == (96, 96, 3) and rgb[seq.read_mask(seq.mask_path(out, info, 0))].mean() > 150
    # by default the crop follows the disc: each frame's own K puts the centre on its centroid
    follow = tmp_path / "follow"
    code, stdout, _ = run(capsys, frames, "--masks", masks, "--out", follow, "--size", 96, "--side", "right",
                          "--K", "300,300,170,115")
    info = seq.validate_sequence_folder(follow)
    assert code == 0 and "following the hand" in stdout and info.principal_points is not None
    expected = np.stack([project(disc_points(6)[index:index + 1], K)[0][0] for index, K in enumerate(info.frame_K())])
    np.testing.assert_allclose(mask_centroids(follow, info), expected, atol=0.35)


def test_video_input_and_a_window_past_the_edge(tmp_path, capsys):
    # the disc hugs the left edge: the window is shifted inside the image horizontally, and
    # is taller than the image, so it is padded vertically
    centres = [[20 + 2 * i, 120] for i in range(5)]
    frames, masks, pixels = draw_clip(tmp_path / "src", frames=5, centres=centres, video=True, masks_as_video=True)
    out = tmp_path / "seq"
    code, _, _ = run(capsys, frames, "--masks", masks, "--out", out, "--size", 64, "--side", "left",
                     "--fov", 60, "--margin", 2)
    assert code == 0
    info = seq.validate_sequence_folder(out)
    assert info.fps == 25 and info.hand_side == "left" and info.metadata["crop"]["x0"] == 0
    assert info.metadata["crop"]["y0"] < 0 and info.metadata["crop"]["side"] > HEIGHT
    K_source = np.array(info.metadata["source_K"])
    np.testing.assert_allclose(K_source[0, 0], 0.5 * WIDTH / np.tan(np.radians(30)))
    # centroids map through the crop exactly as the intrinsics do: u' = fx'/fx (u - cx) + cx'
    scale = info.K[0, 0] / K_source[0, 0]
    expected = (pixels - K_source[:2, 2]) * scale + info.K[:2, 2]
    np.testing.assert_allclose(mask_centroids(out, info), expected, atol=0.6)
    for index in range(5):
        mask = cv2.imread(str(seq.mask_path(out, info, index)), cv2.IMREAD_GRAYSCALE)
        assert set(np.unique(mask)) <= {0, 255}  # lossy mask video binarised


def test_default_camera_is_a_phone_main_camera():
    K, note = si.source_intrinsics(1920, 1080)
    assert "67" in note
    np.testing.assert_allclose(2 * np.degrees(np.arctan(960 / K[0, 0])), 67.0)
    np.testing.assert_allclose(K[:2, 2], [960, 540])
    portrait, _ = si.source_intrinsics(1080, 1920)
    assert portrait[0, 0] == K[0, 0] and portrait[0, 2] == 540


def test_empty_mask_frames_are_left_out_and_recorded(tmp_path, capsys):
    frames, masks, _ = draw_clip(tmp_path / "src", frames=5)
    cv2.imwrite(str(masks / "2.png"), np.zeros((HEIGHT, WIDTH), np.uint8))
    out = tmp_path / "seq"
    code, _, err = run(capsys, frames, "--masks", masks, "--out", out, "--size", 64, "--side", "right")
    assert code == 0 and err == ["warning: left out 1 frame(s) with an empty mask: 2"]
    info = seq.validate_sequence_folder(out)
    assert info.frame_count == 4 and info.metadata["source_frames"] == [0, 1, 3, 4]
    assert info.metadata["dropped_frames"] == {"empty_mask": [2]}


def one_line_error(capsys, *args):
    code, _, err = run(capsys, *args)
    assert code == 1 and len(err) == 1 and err[0].startswith("harp: error: "), err
    return err[0]


def test_bad_input_gives_one_clear_line(tmp_path, capsys):
    frames, masks, _ = draw_clip(tmp_path / "src", frames=4)
    out = tmp_path / "seq"
    common = ["--out", out, "--side", "right", "--size", 64]
    assert "video not found" in one_line_error(capsys, tmp_path / "missing.mp4", "--masks", masks, *common)
    assert "masks not found" in one_line_error(capsys, frames, "--masks", tmp_path / "nowhere", *common)
    corrupt = tmp_path / "corrupt.mp4"
    corrupt.write_bytes(np.random.default_rng(1).integers(0, 255, 5000).astype(np.uint8).tobytes())
    assert "cannot read video" in one_line_error(capsys, corrupt, "--masks", masks, *common)
    empty_folder = tmp_path / "empty"
    empty_folder.mkdir()
    assert "holds no images" in one_line_error(capsys, empty_folder, "--masks", masks, *common)

    (masks / "3.png").unlink()
    assert "4 frames, 3 masks" in one_line_error(capsys, frames, "--masks", masks, *common)
    cv2.imwrite(str(masks / "3.png"), np.zeros((HEIGHT // 2, WIDTH), np.uint8))
    assert "mask 3 is 320x120, frame 3 is 320x240" in one_line_error(capsys, frames, "--masks", masks, *common)
    cv2.imwrite(str(masks / "3.png"), np.full((HEIGHT, WIDTH), 255, np.uint8))
    assert "mask 3 is all foreground" in one_line_error(capsys, frames, "--masks", masks, *common)
    for index in range(4):
        cv2.imwrite(str(masks / f"{index}.png"), np.zeros((HEIGHT, WIDTH), np.uint8))
    assert "every mask is empty" in one_line_error(capsys, frames, "--masks", masks, *common)
    assert not out.exists()  # nothing written on an error

    one_frame = draw_clip(tmp_path / "one", frames=1)
    assert "not enough frames: 1" in one_line_error(capsys, one_frame[0], "--masks", one_frame[1], *common)
    frames, masks, _ = draw_clip(tmp_path / "good", frames=3)
    assert run(capsys, frames, "--masks", masks, *common)[0] == 0
    assert "is not empty" in one_line_error(capsys, frames, "--masks", masks, *common)
    assert run(capsys, frames, "--masks", masks, *common, "--overwrite")[0] == 0
    assert "--K needs four numbers" in one_line_error(capsys, frames, "--masks", masks, *common, "--overwrite",
                                                      "--K", "1,2,3")


def test_natural_order_of_image_names(tmp_path):
    for name in ("10.png", "2.png", "1.png"):
        cv2.imwrite(str(tmp_path / name), np.full((4, 4), int(name.split(".")[0]), np.uint8))
    values = [image[0, 0] for _, image in si.FrameSource(tmp_path, "masks", grey=True)]
    assert values == [1, 2, 10]
