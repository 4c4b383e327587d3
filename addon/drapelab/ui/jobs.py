"""Background jobs of the add-on: a worker thread that never touches bpy and one small shared state object.

The pattern (FLIP Fluids' bake): the operator gathers everything the job needs from bpy on the main thread
(paths, numbers, arrays), starts a Job whose `work(state)` runs on a worker thread and reports through
`state` only; a modal timer operator copies the state into the UI; Cancel (button, Esc) sets
`state.cancel`, which the facade's long calls check between simulation steps (their `cancel_event`). Under
`blender --background` timers and modal operators never run, so the same Job runs synchronously
(`Job.run_sync`). Nothing here is stored in the .blend: a file saved while a job runs reopens idle.

Every Job started is tracked; `cancel_all(timeout)` (called by unregister and at exit) sets every cancel flag
and joins the workers.
"""
import atexit
import threading
import time
import traceback

__all__ = ["JobState", "Job", "IDLE", "RUNNING", "DONE", "FAILED", "CANCELLED", "current", "start", "cancel_all",
           "running_jobs"]

IDLE, RUNNING, DONE, FAILED, CANCELLED = "IDLE", "RUNNING", "DONE", "FAILED", "CANCELLED"
HISTORY_MAX = 500  # loss history entries kept for the live chart


class JobState:
    """What a worker shares with the UI. Writers (the worker) and readers (the UI poll) go through the lock;
    `snapshot()` gives the UI a consistent copy."""

    def __init__(self, kind):
        self.kind = kind
        self.lock = threading.Lock()
        self.cancel = threading.Event()
        self.status = IDLE
        self.fraction = 0.0       # 0..1 of the job as far as it can tell
        self.message = ""
        self.metrics = {}         # latest live numbers (loss, iou, mse, ...)
        self.history = []         # loss per epoch (or other scalar series) for the live chart
        self.error = None         # message of the exception that ended the job
        self.result = None        # what work() returned
        self.started = None
        self.finished = None
        self.cancel_requested_at = None

    def update(self, fraction=None, message=None, **metrics):
        with self.lock:
            if fraction is not None:
                self.fraction = min(1.0, max(0.0, float(fraction)))
            if message is not None:
                self.message = str(message)
            if metrics:
                self.metrics.update(metrics)

    def record(self, value):
        with self.lock:
            self.history.append(float(value))
            del self.history[:-HISTORY_MAX]

    def request_cancel(self):
        with self.lock:
            if self.cancel_requested_at is None:
                self.cancel_requested_at = time.monotonic()
        self.cancel.set()

    @property
    def done(self):
        return self.status in (DONE, FAILED, CANCELLED)

    def snapshot(self):
        with self.lock:
            return {"kind": self.kind, "status": self.status, "fraction": self.fraction, "message": self.message,
                    "metrics": dict(self.metrics), "history": list(self.history), "error": self.error,
                    "elapsed": (self.finished or time.monotonic()) - self.started if self.started else 0.0}


def _is_cancelled(exc):
    try:
        from .._native import Cancelled
    except ImportError:  # the pure-Python tests of this module run without the native module
        Cancelled = KeyboardInterrupt
    return isinstance(exc, (Cancelled, KeyboardInterrupt))


class Job:
    """One job: `work(state)` returns the result or raises. A Cancelled (KeyboardInterrupt) ends it CANCELLED,
    any other exception FAILED with its message in state.error (and the traceback in state.traceback)."""

    def __init__(self, kind, work):
        self.state = JobState(kind)
        self.work = work
        self.thread = None

    def _run(self):
        s = self.state
        with s.lock:
            s.status, s.started = RUNNING, time.monotonic()
        try:
            result = self.work(s)
        except BaseException as e:  # noqa: B902 - a worker must never die silently
            with s.lock:
                if _is_cancelled(e) or s.cancel.is_set():
                    s.status, s.message = CANCELLED, s.message if s.message.startswith("cancel") else "cancelled"
                else:
                    s.status, s.error = FAILED, str(e) or type(e).__name__
                    s.traceback = traceback.format_exc()
                s.finished = time.monotonic()
            return
        with s.lock:
            s.result = result
            s.status = CANCELLED if s.cancel.is_set() and result is None else DONE
            s.fraction = 1.0 if s.status == DONE else s.fraction
            s.finished = time.monotonic()

    def start(self):
        """Runs the job on a daemon worker thread (returns at once)."""
        if self.thread is not None:
            raise RuntimeError(f"{self.state.kind}: job already started")
        self.thread = threading.Thread(target=self._run, name=f"drapelab-{self.state.kind}", daemon=True)
        _track(self)
        self.thread.start()
        return self

    def run_sync(self):
        """Runs the job on the calling thread (blender --background, scripts); returns the state."""
        _track(self)
        self._run()
        return self.state

    def cancel(self):
        self.state.request_cancel()

    def join(self, timeout=None):
        if self.thread is not None:
            self.thread.join(timeout)
        return self.thread is None or not self.thread.is_alive()

    @property
    def alive(self):
        return self.thread is not None and self.thread.is_alive()


_jobs_lock = threading.Lock()
_jobs = {}  # kind -> the latest Job of that kind


def _track(job):
    with _jobs_lock:
        _jobs[job.state.kind] = job


def current(kind=None):
    """The latest job of `kind` (or the latest running one of any kind), or None."""
    with _jobs_lock:
        if kind is not None:
            return _jobs.get(kind)
        live = [j for j in _jobs.values() if j.state.status == RUNNING]
        return live[-1] if live else None


def running_jobs():
    with _jobs_lock:
        return [j for j in _jobs.values() if j.state.status == RUNNING or j.alive]


def start(kind, work, synchronous=False):
    """Starts a job of `kind` unless one of any kind is running (RuntimeError naming it: one long job at a time,
    they share the cores); synchronous runs it on this thread. Returns the Job."""
    busy = running_jobs()
    if busy:
        raise RuntimeError(f"a {busy[0].state.kind} job is running; cancel it or wait for it to finish")
    job = Job(kind, work)
    if synchronous:
        job.run_sync()
    else:
        job.start()
    return job


def cancel_all(timeout=5.0):
    """Sets every job's cancel flag and joins the workers (at most `timeout` seconds in all). Returns the kinds
    whose worker was still alive after that."""
    with _jobs_lock:
        jobs = list(_jobs.values())
    for j in jobs:
        if j.alive:
            j.cancel()
    deadline = time.monotonic() + timeout
    stuck = [j.state.kind for j in jobs if not j.join(max(0.0, deadline - time.monotonic()))]
    return stuck


def forget_finished():
    """Drops finished jobs (unregister: a re-registered add-on starts with no job)."""
    with _jobs_lock:
        for k in [k for k, j in _jobs.items() if not j.alive and j.state.status != RUNNING]:
            del _jobs[k]


atexit.register(cancel_all, 5.0)
