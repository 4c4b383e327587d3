"""Module-level job factories for tests/python/test_addon_process_jobs.py: a worker process rebuilds a
drapelab.ui.jobs.Task by importing its factory, so the factories live in an importable module (the test puts
this folder on the worker's PYTHONPATH)."""
import os
import time


def counting_work(steps, step_seconds=0.0, fail_at=None, crash_at=None, ignore_cancel=False):
    """Counts to `steps`, reporting each step; raises ValueError at `fail_at`, dies without a word at `crash_at`;
    checks the cancel flag between steps unless `ignore_cancel`."""
    if steps < 1:
        raise ValueError(f"steps: must be >= 1, got {steps}")

    def work(state):
        for i in range(steps):
            if not ignore_cancel and state.cancel.is_set():
                return None
            if fail_at == i:
                raise ValueError(f"step {i}: bad value")
            if crash_at == i:
                os._exit(3)
            state.update((i + 1) / steps, f"step {i + 1}/{steps}", step=i + 1)
            state.record(float(i))
            time.sleep(step_seconds)
        return {"pid": os.getpid(), "steps": steps}

    return work
