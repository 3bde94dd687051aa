"""Batch workers (pipeline/fit/batch_workers.py): another process takes part of every batch; the
energy and gradients add up to the single-process ones, and a worker's failure is one line."""
import numpy as np
import pytest
import torch

from pipeline.evaluate.exact_clips import write_clip
from pipeline.fit import fitting
from pipeline.fit.batch_workers import BatchWorkers
from pipeline.fit.checkpoint import FitState
from pipeline.fit.problem import FitError
from pipeline.fit.schedule import StageKind
from pipeline.fit.stage_run import StageRun, chunked_energy, split_batch
from pipeline.init import initialise_sequence
from synth.motions import OPEN


def test_a_batch_splits_into_near_equal_parts():
    parts = split_batch(torch.arange(7), 2)
    assert [part.tolist() for part in parts] == [[0, 1, 2, 3], [4, 5, 6]]
    assert [part.tolist() for part in split_batch(torch.arange(1), 3)] == [[0]]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    folder = tmp_path_factory.mktemp("workers") / "clip"
    write_clip(folder, OPEN, frames=8, size=96, turn_degrees=30)
    initialise_sequence(folder, "gt-noise", log=lambda *a: None)
    job = fitting.FitJob(device="cpu")
    # no texture regularisers: they draw random offsets, which a worker draws from its own seed
    weights = {**fitting.settings_for("fast", 8).weights, "texture": 0.0, "normal_map": 0.0}
    return fitting._set_up(folder, job, {"resolution": 96, "texture_size": 64, "batch_size": 6, "shadows": "off",
                                         "weights": weights, "validation_frames": 0})


@pytest.mark.parametrize("kind", [StageKind.ALIGN, StageKind.JOINT])
def test_the_parts_add_up_as_in_one_process(setup, kind):
    """The worker's part and the fit's add up to what one process gives for the same two parts
    (each part's terms averaged over its own pixels, weighted by its share of the frames), and
    within a percent of the whole batch's energy."""
    problem = setup.problem
    schedule = problem.settings.schedule()
    stage = next(stage for stage in schedule if stage.kind is kind)
    batch = torch.arange(6)

    def gradients():
        return {name: p.grad.clone() for name, p in problem.avatar.named_parameters() if p.grad is not None}

    def run():
        run = StageRun(problem, stage, FitState.fresh(schedule, "off"), torch.Generator().manual_seed(0))
        run.optimiser.zero_grad(set_to_none=True)
        return run

    whole = run().energy(batch)[0]
    run()
    parts = [chunked_energy(problem, stage, part, 32, len(batch), False, torch.Generator())
             for part in split_batch(batch, 2)]
    alone = sum(loss for loss, _ in parts), gradients()
    problem.workers = workers = BatchWorkers(problem, setup.recipe, 1)
    try:
        shared = run().energy(batch)[0], gradients()
    finally:
        workers.close()
        problem.workers = None
    assert shared[0] == pytest.approx(alone[0], rel=1e-5) and shared[0] == pytest.approx(whole, rel=1e-2)
    assert set(shared[1]) == set(alone[1])
    for name, gradient in alone[1].items():
        scale = float(gradient.abs().max()) or 1.0
        assert float((shared[1][name] - gradient).abs().max()) <= 1e-4 * scale, name


def test_a_failing_worker_is_one_line(setup):
    problem = setup.problem
    workers = BatchWorkers(problem, setup.recipe, 1)
    processes = list(workers.processes)
    stage = problem.settings.schedule()[1]
    try:
        workers.send(workers.connections[0], stage, torch.tensor([99]), 6, 6, False, 0)   # no frame 99
        with pytest.raises(FitError, match="a batch worker failed: IndexError"):
            workers.collect(workers.connections[0])
    finally:
        workers.close()
    assert not any(process.is_alive() for process in processes)


def test_a_fit_with_workers_repeats_itself(setup, tmp_path):
    sequence = setup.recipe["sequence"]
    options = dict(progress="none", max_steps=6, texture_size=64, batch_size=6, resolution=96, shadows="off",
                   device="cpu", workers=2, solve_albedo=False)
    first = fitting.fit(sequence, tmp_path / "first", **options)
    second = fitting.fit(sequence, tmp_path / "second", **options)
    assert first["final_losses"] == second["final_losses"] and np.isfinite(first["metrics"]["psnr_mean"])
