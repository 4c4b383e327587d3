"""The add-on's worker processes (drapelab.ui.jobs.ProcessJob, drapelab.ui.worker): what the UI starts runs in
another process (Blender's Python is not thread safe), reports progress through a pipe read without blocking,
returns its result, fails with the work's message, cancels within a second, and a worker that ignores Cancel or
dies is handled (killed at exit; a clear error)."""
import os
import time

import pytest

from drapelab.ui import jobs

import job_factories

HERE = os.path.dirname(os.path.abspath(__file__))


@pytest.fixture(autouse=True)
def worker_env(monkeypatch):
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([HERE, os.environ.get("PYTHONPATH", "")]))
    yield
    jobs.cancel_all(timeout=10.0)
    jobs.forget_finished()


def wait(job, seconds=60.0):
    assert job.join(seconds), f"{job.state.kind}: still running after {seconds} s"
    return job.state


def test_a_task_runs_in_a_worker_process_with_progress_history_and_result():
    job = jobs.start("count", jobs.Task(job_factories.counting_work, 5, step_seconds=0.05))
    assert isinstance(job, jobs.ProcessJob) and jobs.current() is job
    state = wait(job)
    assert state.status == jobs.DONE, state.error
    assert state.result["steps"] == 5 and state.result["pid"] != os.getpid()
    snap = state.snapshot()
    assert snap["history"] == [0.0, 1.0, 2.0, 3.0, 4.0] and snap["metrics"]["step"] == 5
    assert snap["fraction"] == 1.0 and snap["message"] == "step 5/5"


def test_the_same_task_runs_synchronously_in_this_process():
    state = jobs.start("count", jobs.Task(job_factories.counting_work, 3), synchronous=True).state
    assert state.status == jobs.DONE and state.result["pid"] == os.getpid()


def test_bad_arguments_are_an_error_before_anything_starts():
    with pytest.raises(ValueError, match="steps: must be >= 1"):
        jobs.Task(job_factories.counting_work, 0)
    assert jobs.current() is None


def test_a_failing_task_reports_the_works_message():
    state = wait(jobs.start("count", jobs.Task(job_factories.counting_work, 5, fail_at=2)))
    assert state.status == jobs.FAILED and state.error == "step 2: bad value"
    assert "ValueError" in state.traceback and state.history == [0.0, 1.0]


def test_cancel_stops_the_worker_within_a_second_and_keeps_what_it_reported():
    job = jobs.start("count", jobs.Task(job_factories.counting_work, 10000, step_seconds=0.01))
    while job.alive and job.state.snapshot()["metrics"].get("step", 0) < 3:
        time.sleep(0.02)
    t = time.monotonic()
    job.cancel()
    state = wait(job, 5.0)
    assert time.monotonic() - t < 1.0 and state.status == jobs.CANCELLED
    assert len(state.history) >= 3 and job.process.returncode == 0


def test_a_worker_that_dies_is_a_clear_failure():
    state = wait(jobs.start("count", jobs.Task(job_factories.counting_work, 5, crash_at=1)))
    assert state.status == jobs.FAILED and "exit code 3" in state.error


def test_a_worker_that_ignores_cancel_is_killed_at_exit():
    job = jobs.start("count", jobs.Task(job_factories.counting_work, 10000, step_seconds=0.01, ignore_cancel=True))
    time.sleep(0.3)
    assert jobs.cancel_all(timeout=0.5) == ["count"]
    assert job.process.poll() is not None and not job.alive and job.state.status == jobs.CANCELLED


def test_one_job_at_a_time_across_backends():
    job = jobs.start("count", jobs.Task(job_factories.counting_work, 10000, step_seconds=0.01))
    with pytest.raises(RuntimeError, match="a count job is running"):
        jobs.start("other", lambda s: None)
    job.cancel()
    wait(job, 5.0)


def test_a_calibration_pickles_as_its_numbers():
    import pickle
    from drapelab import measure
    c = pickle.loads(pickle.dumps(measure.calibration(4000.0, (512.5, 300.25))))
    assert (c.px_per_m, c.cx, c.cy) == (4000.0, 512.5, 300.25)
    d = pickle.loads(pickle.dumps(measure.calibration(4000.0, None)))
    assert not d.has_centre


def test_work_that_cannot_reach_a_process_is_an_error_before_it_starts():
    with pytest.raises(RuntimeError, match="cannot be sent to a worker process"):
        jobs.start("count", jobs.Task(job_factories.counting_work, 3, step_seconds=lambda: None))
    assert jobs.current() is None
