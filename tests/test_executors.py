"""pipeline/executors.py: cells run in order here, in worker processes or as Ray tasks; a cell
after the cells it needs; failures recorded without stopping the others; folders shipped to a
Ray task and back; a task whose worker dies run again, going on from what it left."""
import importlib.util
import os
from pathlib import Path

import pytest

from pipeline.executors import Cell, CellFailure, ExecutorError, run_cells

ray_installed = importlib.util.find_spec("ray") is not None
needs_ray = pytest.mark.skipif(not ray_installed, reason="Ray (the cluster extra) is not installed")


def square(value, log):
    log(f"squaring {value}")
    return {"value": value * value, "process": os.getpid()}


def fail(value, log):
    raise ValueError(f"no hand found in clip {value}\nsecond line")


def read_text(path, log):
    return Path(path).read_text()


def write_text(path, text, log):
    Path(path).write_text(text)
    return text


def append_in_folder(folder, text, log):
    """Reads the folder's notes, adds a line: what a fit does with its checkpoint folder."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    notes = folder / "notes.txt"
    before = notes.read_text() if notes.exists() else ""
    notes.write_text(before + text + "\n")
    return {"lines": len((before + text).splitlines()), "process": os.getpid()}


def dies_once(folder, log):
    """Leaves a checkpoint, then kills its own process the first time; run again, it goes on from
    the checkpoint."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    checkpoint = folder / "checkpoint.txt"
    if not checkpoint.exists():
        checkpoint.write_text("half done\n")
        os._exit(1)                 # the worker dies mid-work
    return {"resumed_from": checkpoint.read_text().strip()}


RUNS = [dict(executor="local", jobs=1), dict(executor="local", jobs=2),
        pytest.param(dict(executor="ray"), marks=needs_ray)]


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray of 2 CPUs for the module's Ray tests."""
    if not ray_installed:
        yield None
        return
    import ray
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False,
             runtime_env={"env_vars": {"PYTHONPATH": os.pathsep.join(   # the code, and this module's cells
                 str(folder) for folder in Path(__file__).resolve().parents[:2])}})
    yield ray
    ray.shutdown()


@pytest.mark.parametrize("run", RUNS)
def test_cells_run_after_what_they_need_and_failures_are_named(tmp_path, run, local_ray):
    target = str(tmp_path / "first.txt")
    cells = [Cell("write", write_text, {"path": target, "text": "from the first cell"}),
             Cell("read", read_text, {"path": target}, after=("write",)),
             Cell("square", square, {"value": 7}),
             Cell("broken", fail, {"value": 3}),
             Cell("after broken", square, {"value": 2}, after=("broken",))]
    seen = []
    with pytest.raises(CellFailure) as caught:
        run_cells(cells, threads=1, log=lambda message: None, logs=tmp_path / "logs",
                  on_result=lambda name, result: seen.append(name), **run)
    assert caught.value.failures == {"broken": "ValueError: no hand found in clip 3",
                                     "after broken": "needs broken, which failed"}
    assert set(caught.value.results) == set(seen) == {"write", "read", "square"}
    assert caught.value.results["read"] == "from the first cell"
    results = run_cells(cells[:3], threads=1, log=lambda message: None, logs=tmp_path / "logs", **run)
    assert results["square"]["value"] == 49
    if run.get("jobs", 2) > 1:        # in a worker process, its log lines in its own file
        assert results["square"]["process"] != os.getpid()
        assert "squaring 7" in (tmp_path / "logs" / "square.log").read_text()
        assert "no hand found in clip 3" in (tmp_path / "logs" / "broken.log").read_text()


@needs_ray
def test_a_ray_task_works_on_a_shipped_copy_of_its_folder_which_comes_back(tmp_path, local_ray):
    folder = tmp_path / "clip"
    folder.mkdir()
    (folder / "notes.txt").write_text("imported\n")
    cells = [Cell("fit", append_in_folder, {"folder": str(folder), "text": "fitted"}, ship=("folder",))]
    results = run_cells(cells, executor="ray", threads=1, ship="always", log=lambda message: None)
    assert results["fit"]["lines"] == 2                          # it read what the driver had
    assert (folder / "notes.txt").read_text() == "imported\nfitted\n"     # and its work came back
    assert not list(tmp_path.glob("*.incoming"))


@needs_ray
def test_a_ray_task_whose_worker_dies_runs_again_from_its_checkpoint(tmp_path, local_ray):
    cells = [Cell("dies once", dies_once, {"folder": str(tmp_path / "fit")}), Cell("square", square, {"value": 3})]
    results = run_cells(cells, executor="ray", threads=1, log=lambda message: None)
    assert results["dies once"] == {"resumed_from": "half done"} and results["square"]["value"] == 9


def test_a_plan_that_names_an_unknown_or_repeated_cell_or_executor_is_refused():
    with pytest.raises(ValueError, match="unknown cells: missing"):
        run_cells([Cell("a", square, {"value": 1}, after=("missing",))])
    with pytest.raises(ValueError, match="unique"):
        run_cells([Cell("a", square, {"value": 1}), Cell("a", square, {"value": 2})])
    with pytest.raises(ExecutorError, match="unknown executor 'dask'"):
        run_cells([Cell("a", square, {"value": 1})], executor="dask")


def test_without_ray_the_ray_executor_says_how_to_install_it(without_ray):
    with pytest.raises(ExecutorError, match=r"pip install \.\[cluster\]"):
        run_cells([Cell("a", square, {"value": 1})], executor="ray")
