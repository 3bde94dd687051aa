"""The add-on's worker jobs with the real fitting engine (this Python, which has torch): progress,
cancel, resume and bind; a worker that fails is one line."""
import sys
import textwrap
import time

import pytest

torch = pytest.importorskip("torch")
bpy = pytest.importorskip("bpy")

from harp_addon import actions, engine, jobs  # noqa: E402
from pipeline.formats import avatar_folder as av  # noqa: E402

pytestmark = [pytest.mark.blender, pytest.mark.usefixtures("one_torch_thread")]


@pytest.fixture(scope="module")
def exact_clip(tmp_path_factory):
    from pipeline.evaluate.exact_clips import write_clip
    from pipeline.init import initialise_sequence
    from synth.motions import RELAXED

    folder = tmp_path_factory.mktemp("exact") / "clip"
    write_clip(folder, RELAXED, frames=4, size=96)
    initialise_sequence(folder, "gt-noise", log=lambda message: None)
    return folder


def test_worker_round_trip_progress_cancel_resume_bind(exact_clip, tmp_path, empty_scene):
    out = tmp_path / "avatar"
    running = actions.start_fit("test", exact_clip, out, python=sys.executable, extra=["--max-steps", "60"])
    progress = []
    while running.job.active and not progress:
        progress += [event for event in running.job.poll() if event.kind == "progress"]
        time.sleep(0.05)    # as Blender's timer would: a busy loop here starves the worker
    first = progress[0]
    assert (first.stage_number, first.stage_count) == (1, 4)    # the alignment, then three stages
    assert running.job.status_line().startswith(f"stage 1/4: {first.stage}: step ")
    actions.cancel("test")
    assert running.job.wait(timeout=240) == "cancelled", list(running.job.errors)
    assert progress and (out / "checkpoint.pt").is_file() and not (out / av.AVATAR_FILE).exists()
    assert "checkpoint saved" in actions.status_line(running)
    resumed = actions.start_fit("test", exact_clip, out, python=sys.executable, resume=True,
                                extra=["--max-steps", "60"])
    events = []
    while resumed.job.active:
        events += [event for event in resumed.job.poll() if event.kind == "progress"]
        time.sleep(0.05)
    assert resumed.job.state == "finished", list(resumed.job.errors)
    done = [event.done for event in events]
    assert done == sorted(done) and events[-1].done == events[-1].total
    numbers = [event.stage_number for event in events]
    assert numbers == sorted(numbers) and numbers[-1] == 4 and len(set(numbers)) >= 3
    assert any("resum" in line or "fitting" in line for line in resumed.job.log)
    bound = actions.bind(out)
    assert len(bound.frames) == 4


def test_worker_problems_are_one_line(exact_clip, tmp_path):
    with pytest.raises(actions.ActionError, match="no Python at /nowhere/python"):
        actions.start_fit("bad", exact_clip, tmp_path / "a", python="/nowhere/python")
    crash = jobs.Job([[sys.executable, "-c", textwrap.dedent("""
        import json, sys
        print(json.dumps({"event": "progress", "stage": "geometry", "step": 1, "loss": 0.5, "done": 1, "total": 9,
                          "seconds_left": 8.0}), flush=True)
        raise RuntimeError("the worker broke mid-fit")""")]], "fit").start()
    assert crash.wait(timeout=60) == "failed"
    assert crash.progress.done == 1 and "RuntimeError: the worker broke mid-fit" in crash.status_line()
    assert engine.check_engine("/nowhere/python").message == "no Python at /nowhere/python"
    status = engine.check_engine(sys.executable)
    assert status.ok and status.torch == torch.__version__ and "cpu" in status.device


def test_progress_lines():
    event = jobs.parse_progress_line('{"event": "progress", "stage": "align", "step": 3, "loss": 0.25, "done": 3, '
                                     '"total": 30, "seconds_left": 81.0}\n')
    assert (event.kind, event.stage, event.done, event.total, event.loss) == ("progress", "align", 3, 30, 0.25)
    assert event.stage_number is None     # lines from before the stage numbers still parse
    event = jobs.parse_progress_line('{"event": "progress", "stage": "geometry", "step": 3, "loss": 0.25, "done": 3, '
                                     '"total": 30, "seconds_left": 81.0, "stage_number": 2, "stage_count": 4}')
    assert (event.stage_number, event.stage_count) == (2, 4)
    assert jobs.parse_progress_line('{"event": "log", "message": "shadows auto"}').message == "shadows auto"
    assert jobs.parse_progress_line("plain text").kind == "log" and jobs.parse_progress_line("  ") is None


def test_esc_stops_the_running_job_as_cancel_does():
    job = jobs.Job([[sys.executable, "-c", "import signal, time; signal.signal(signal.SIGINT, "
                                           "signal.default_int_handler); time.sleep(60)"]], "fit").start()
    actions.JOBS["esc"] = actions.Running(job, "fit", None, "esc")
    try:
        assert actions.key_pressed("esc", "A", "PRESS") == "ignored"
        assert actions.key_pressed("esc", "ESC", "RELEASE") == "ignored" and job.active
        assert actions.key_pressed("esc", "ESC", "PRESS") == "cancelled"
        assert job.wait(timeout=60) == "cancelled"
        assert actions.key_pressed("esc", "ESC", "PRESS") == "idle"      # the listener stops with the job
    finally:
        actions.JOBS.pop("esc", None)
    assert actions.key_pressed("no such scene", "ESC", "PRESS") == "idle"


def test_harp_takes_interrupts_even_when_started_ignoring_them():
    import subprocess

    result = subprocess.run([sys.executable, "-c", textwrap.dedent("""
        import signal, sys
        signal.signal(signal.SIGINT, signal.SIG_IGN)          # as a shell's background job starts
        from pipeline import cli
        cli._take_interrupts()
        print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)""")], capture_output=True, text=True,
                            timeout=60)
    assert result.stdout.strip() == "True", result.stderr


def test_a_cancelled_worker_stops_even_if_the_interrupt_is_lost_or_ignored(monkeypatch):
    # interrupted at once, while the worker starts: an interrupt that lands before Python is ready can be lost.
    # The worker takes interrupts as harp does (cli._take_interrupts), whatever this test's process ignores.
    worker = "import signal, time; signal.signal(signal.SIGINT, signal.default_int_handler); time.sleep(60)"
    for _ in range(3):
        job = jobs.Job([[sys.executable, "-c", worker]], "fit").start()
        job.cancel()
        assert job.wait(timeout=30) == "cancelled"
    # a worker that ignores the interrupt is killed after the grace period
    monkeypatch.setattr(jobs, "CANCEL_GRACE_SECONDS", 1.0)
    stubborn = jobs.Job([[sys.executable, "-c", textwrap.dedent("""
        import signal, time
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        print("ready", flush=True)
        time.sleep(60)""")]], "fit").start()
    while not stubborn.log:
        stubborn.poll()
        time.sleep(0.05)
    stubborn.cancel()
    started = time.time()
    assert stubborn.wait(timeout=30) == "cancelled" and time.time() - started < 10
