"""The stability sweep's cases (pipeline/evaluate/stability.py): every clip it spoils is spoilt
as its case says, every case ends finite, and each is compared with the unperturbed fit."""
import dataclasses

import cv2
import numpy as np
import pytest

from pipeline.evaluate import stability
from pipeline.evaluate.exact_clips import write_clip
from pipeline.evaluate.stability import (CLIP_CASES, SCALES, SweepCase, _clip_spec, _compare_with_baseline,
                                         holed_mask, run_stability_sweep, sweep_cases, write_sweep_clip)
from pipeline.evaluate.study_report import markdown, write_outputs
from pipeline.formats import sequence_folder as seq


def test_every_kind_of_case_is_in_the_sweep_with_the_baseline_first():
    cases = sweep_cases()
    assert cases[0].kind == "baseline" and len({case.key for case in cases}) == len(cases)
    assert {case.kind for case in cases} == {"baseline", "weights", "rates", "poses", "shapes", "framing", "inputs"}
    assert [case.kind for case in sweep_cases(quick=True)] == ["baseline", "poses", "shapes", "framing", "inputs",
                                                              "rates", "weights"]


def test_the_fast_scale_frames_a_hand_600_and_50_px_across(tmp_path):
    fast = SCALES["fast"]
    for clip, expected_px, image_px in (("large_hand", 600, 720), ("small_hand", 50, 256)):
        spec = _clip_spec(clip, fast)
        assert spec["size"] == image_px and spec["frames"] == 30
        spec.update(frames=1)
        info = write_clip(tmp_path / clip, spec.pop("pose"), **spec)
        rows = np.nonzero(seq.read_mask(seq.mask_path(tmp_path / clip, info, 0)).any(1))[0]
        assert abs((rows.max() - rows.min() + 1) - expected_px) <= 0.05 * expected_px


def test_spoilt_clips_differ_from_the_clean_one_only_where_their_case_says(tmp_path):
    tiny = SCALES["tiny"]
    clean = write_sweep_clip(tmp_path / "relaxed", "relaxed", tiny)
    info = seq.read_sequence_info(clean)
    for name in ("mask_holes", "underexposed", "overexposed"):
        write_sweep_clip(tmp_path / name, name, tiny)
    for index in range(info.frame_count):
        mask = seq.read_mask(seq.mask_path(clean, info, index))
        holed = seq.read_mask(seq.mask_path(tmp_path / "mask_holes", info, index))
        assert not (holed & ~mask).any() and (mask & ~holed).sum() > 0       # pixels only removed, inside the hand
        frame = cv2.imread(str(seq.frame_path(clean, info, index))).astype(float)
        dark = cv2.imread(str(seq.frame_path(tmp_path / "underexposed", info, index))).astype(float)
        bright = cv2.imread(str(seq.frame_path(tmp_path / "overexposed", info, index))).astype(float)
        if index % 3 == 1:
            assert dark.mean() == pytest.approx(0.25 * frame.mean(), rel=0.02) and bright.mean() > 1.5 * frame.mean()
        else:
            assert (dark == frame).all() and (bright == frame).all()
    assert (seq.read_sequence_info(write_sweep_clip(tmp_path / "one", "one_frame", tiny)).frame_count,
            seq.read_sequence_info(write_sweep_clip(tmp_path / "three", "three_frames", tiny)).frame_count) == (1, 3)


def test_a_holed_mask_is_never_empty():
    tiny = np.zeros((40, 40), bool)
    tiny[18:22, 18:22] = True
    assert (holed_mask(tiny, np.random.default_rng(0)) > 0).sum() >= seq.MIN_MASK_PIXELS


def test_each_case_is_compared_with_the_unperturbed_fit():
    rows = [dict(kind="baseline", case="unperturbed", finite=True, joint_mm=2.0, l1_mean=0.04, degraded=False),
            dict(kind="weights", case="a", finite=True, joint_mm=2.3, l1_mean=0.05, degraded=False),
            dict(kind="weights", case="b", finite=True, joint_mm=2.5, l1_mean=0.04, degraded=False),
            dict(kind="inputs", case="c", finite=True, joint_mm=4.0, l1_mean=0.08, degraded=True),
            dict(kind="inputs", case="d", finite=False, joint_mm=None, l1_mean=None, degraded=True)]
    _compare_with_baseline(rows)
    assert [row["joint_ratio"] for row in rows[:4]] == pytest.approx([1.0, 1.15, 1.25, 2.0])
    assert rows[4]["joint_ratio"] is None and rows[4]["l1_ratio"] is None
    assert rows[1]["joint_ratio"] == pytest.approx(1.15) and rows[1]["l1_ratio"] == pytest.approx(1.25)
    assert [row["within_baseline"] for row in rows] == [True, True, False, None, None]


def test_every_clip_case_ends_finite_and_the_report_draws_their_curves(tmp_path, monkeypatch):
    monkeypatch.setitem(SCALES, "tiny", dataclasses.replace(SCALES["tiny"], curves=True))
    cases = [SweepCase("baseline", "unperturbed", "relaxed", {}, False)]
    cases += [SweepCase(kind, name, clip, {}, degraded) for kind, name, clip, degraded in CLIP_CASES]
    section = run_stability_sweep(tmp_path / "sweep", quick=True, scale="tiny", log=lambda message: None,
                                  cases=cases)
    assert section["all_finite"] and section["steps_per_stage"] == 4, [row for row in section["rows"]
                                                                        if not row["finite"]]
    assert len(section["rows"]) == len(cases) and section["rows"][0]["joint_ratio"] == pytest.approx(1.0)
    assert all(row["joint_ratio"] is not None and row["l1_ratio"] is not None for row in section["rows"])
    study = {"dataset": "", "preset": "fast", "quick": True, "fit_options": {}, "sections": {"stability": section},
             "seconds": 1.0}
    write_outputs(tmp_path / "study", study)
    assert (tmp_path / "study" / "plots" / "stability.png").is_file()
    text = markdown(study)
    assert text.count("plots/stability.png") == 1 and "| inputs | 1 frame | yes | yes |" in text
    # a rerun finds every result and fits nothing
    monkeypatch.setattr(stability, "_run_case", lambda *args: pytest.fail("refitted a finished case"))
    again = run_stability_sweep(tmp_path / "sweep", quick=True, scale="tiny", log=lambda message: None, cases=cases)
    assert [row["joint_mm"] for row in again["rows"]] == [row["joint_mm"] for row in section["rows"]]


def test_the_sweep_can_be_run_and_reported_kind_by_kind(tmp_path):
    with pytest.raises(ValueError, match="no stability cases of kind 'colours'"):
        run_stability_sweep(tmp_path, kinds=("colours",))
    section = run_stability_sweep(tmp_path / "sweep", quick=True, scale="tiny", log=lambda message: None,
                                  kinds=("baseline",))
    assert [row["kind"] for row in section["rows"]] == ["baseline"] and section["all_finite"]
