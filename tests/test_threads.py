"""The fit's CPU threads (pipeline/threads.py): the `harp` command sets the count and, before
torch starts OpenMP, passive waiting; an explicit choice of the user's wins."""
import json
import os
import subprocess
import sys

import pytest

from pipeline.threads import configure_threads, default_threads

PROBE = """
import json, sys
from pipeline.threads import configure_threads
effect = configure_threads({threads})
import os, torch
print(json.dumps({{**effect, "torch_threads": torch.get_num_threads(), "env": os.environ.get("OMP_WAIT_POLICY")}}))
"""


def probe(threads, environment=None):
    env = {key: value for key, value in os.environ.items() if key not in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS")}
    env.update(environment or {})
    result = subprocess.run([sys.executable, "-c", PROBE.format(threads=threads)], capture_output=True, text=True,
                            env=env, check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_default_is_half_the_cores_with_passive_waiting():
    effect = probe(None)
    assert effect["threads"] == effect["torch_threads"] == default_threads()
    assert default_threads() == max(1, len(os.sched_getaffinity(0)) // 2)
    assert effect["env"] == effect["wait_policy"] == "PASSIVE"


def test_an_explicit_count_and_the_users_wait_policy_win():
    effect = probe(3, {"OMP_WAIT_POLICY": "ACTIVE"})
    assert effect["torch_threads"] == 3 and effect["env"] == "ACTIVE"


def test_a_count_below_one_is_one_clear_error():
    with pytest.raises(ValueError, match="--threads must be at least 1"):
        configure_threads(0)


def test_harp_fit_reports_its_threads(tmp_path):
    """`harp fit --threads 1` on a tiny clip: report.json says 1 thread, passive waiting."""
    from synth_clips import render_tiny_clip

    pytest.importorskip("bpy")
    clip = render_tiny_clip(tmp_path / "clip", frames=2)
    env = {key: value for key, value in os.environ.items() if key != "OMP_WAIT_POLICY"}
    subprocess.run([sys.executable, "-m", "pipeline.cli", "fit", str(clip), "--out", str(tmp_path / "avatar"),
                    "--threads", "1", "--max-steps", "1", "--progress", "none", "--no-solve-albedo"],
                   check=True, capture_output=True, env=env)
    report = json.loads((tmp_path / "avatar" / "report.json").read_text())
    assert report["cpu_threads"] == 1 and report["omp_wait_policy"] == "PASSIVE"
