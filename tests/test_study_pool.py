"""study_pool.run_cells: cells in order here or in worker processes, a cell after the cells it
needs, and failures recorded without stopping the others."""
import os

import pytest

from pipeline.evaluate.study_pool import Cell, CellFailure, run_cells


def square(value, log):
    log(f"squaring {value}")
    return {"value": value * value, "process": os.getpid()}


def fail(value, log):
    raise ValueError(f"no hand found in clip {value}\nsecond line")


def written_after(path, log):
    """Reads what the cell it comes after wrote."""
    with open(path) as handle:
        return handle.read()


def write(path, text, log):
    with open(path, "w") as handle:
        handle.write(text)
    return text


@pytest.mark.parametrize("jobs", [1, 2])
def test_cells_run_after_what_they_need_and_failures_are_named(tmp_path, jobs):
    target = str(tmp_path / "first.txt")
    cells = [Cell("write", write, {"path": target, "text": "from the first cell"}),
             Cell("read", written_after, {"path": target}, after=("write",)),
             Cell("square", square, {"value": 7}),
             Cell("broken", fail, {"value": 3}),
             Cell("after broken", square, {"value": 2}, after=("broken",))]
    with pytest.raises(CellFailure) as caught:
        run_cells(cells, jobs=jobs, threads=1, log=lambda message: None, logs=tmp_path / "logs")
    assert caught.value.failures == {"broken": "ValueError: no hand found in clip 3",
                                     "after broken": "needs broken, which failed"}
    results = run_cells(cells[:3], jobs=jobs, threads=1, log=lambda message: None, logs=tmp_path / "logs")
    assert results["read"] == "from the first cell" and results["square"]["value"] == 49
    if jobs > 1:        # in a worker process, its log lines in its own file
        assert results["square"]["process"] != os.getpid()
        assert "squaring 7" in (tmp_path / "logs" / "square.log").read_text()
        assert "no hand found in clip 3" in (tmp_path / "logs" / "broken.log").read_text()


def test_a_plan_that_names_an_unknown_or_repeated_cell_is_refused():
    with pytest.raises(ValueError, match="unknown cells: missing"):
        run_cells([Cell("a", square, {"value": 1}, after=("missing",))])
    with pytest.raises(ValueError, match="unique"):
        run_cells([Cell("a", square, {"value": 1}), Cell("a", square, {"value": 2})])
