"""Background jobs of the add-on: a worker that never touches bpy and one small shared state object.

The pattern (FLIP Fluids' bake): the operator gathers everything the job needs from bpy on the main thread
(paths, numbers, arrays), starts a job whose `work(state)` reports through `state` only; a modal timer operator
copies the state into the UI; Cancel (button, Esc) sets `state.cancel`, which the facade's long calls check
between simulation steps (their `cancel_event`). Under `blender --background` timers and modal operators never
run, so the same work runs synchronously (`Job.run_sync`). Nothing here is stored in the .blend: a file saved
while a job runs reopens idle.

Two backends:
- `Task(factory, *args, **kwargs)` (what the operators start from the UI) runs in a worker *process*
  (`drapelab.ui.worker`, the system Python Blender embeds): Blender's Python is not thread safe, and a Python
  thread left running beside Blender's event loop crashes it at random (Blender's "Troubleshooting Errors &
  Crashes": threads must finish before the script does). The process reports over a pipe that the main thread
  drains without blocking (`ProcessJob.poll`, called by `current()`, `alive` and the modal operator's timer);
  Cancel writes to the process's stdin, and a process that does not stop is killed at exit.
- A plain callable runs on a worker thread (`Job`): scripts and tests that join it before they return.

Every job started is tracked; `cancel_all(timeout)` (called by unregister and at exit) sets every cancel flag
and waits for the workers (processes still running after that are killed).
"""
import atexit
import os
import pickle
import struct
import subprocess
import sys
import threading
import time
import traceback

__all__ = ["JobState", "Job", "Task", "ProcessJob", "IDLE", "RUNNING", "DONE", "FAILED", "CANCELLED", "current", "start", "cancel_all",
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


class Task:
    """A job's work as a module-level factory and its arguments, so that a worker process can rebuild it:
    `factory(*args, **kwargs)` checks the arguments (bad input is an error here, at once) and returns
    `work(state)`. Calling the Task runs that work in this process."""

    def __init__(self, factory, *args, **kwargs):
        self.factory, self.args, self.kwargs = factory, args, kwargs
        self.work = factory(*args, **kwargs)

    def __call__(self, state):
        return self.work(state)

    def __getstate__(self):  # the worker process gets the recipe, not the closure
        return {"factory": (self.factory.__module__, self.factory.__qualname__), "args": self.args,
                "kwargs": self.kwargs}

    def __setstate__(self, d):
        import importlib
        module, name = d["factory"]
        self.factory = getattr(importlib.import_module(module), name)
        self.args, self.kwargs = d["args"], d["kwargs"]
        self.work = self.factory(*self.args, **self.kwargs)


def worker_python():
    """The interpreter for worker processes: $DRAPELAB_PYTHON, else the system Python Blender embeds
    (sys.executable inside Blender is Blender itself or whatever `python3` a shell would find)."""
    if os.environ.get("DRAPELAB_PYTHON"):
        return os.environ["DRAPELAB_PYTHON"]
    v = sys.version_info
    for candidate in (os.path.join(sys.base_prefix, "bin", f"python{v.major}.{v.minor}"),
                      os.path.join(sys.base_prefix, "bin", "python3"), "/usr/bin/python3"):
        if os.access(candidate, os.X_OK):
            return candidate
    return sys.executable


def write_message(stream, message):
    """One length-prefixed pickle on `stream` (the worker's reports)."""
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(struct.pack("<I", len(data)) + data)
    stream.flush()


class ProcessJob(Job):
    """A Task run by `python -m drapelab.ui.worker`: the same state, filled from the worker's messages
    ("update", "record", then "end" with status, result and error) as poll() reads them."""

    def __init__(self, kind, task):
        super().__init__(kind, task)
        self.process = None
        self._buffer = b""
        self._ended = False

    def start(self):
        if self.process is not None:
            raise RuntimeError(f"{self.state.kind}: job already started")
        package_parent = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([package_parent] + [p for p in (env.get("PYTHONPATH") or "").split(os.pathsep) if p])
        try:  # what cannot travel to a process is the caller's error, before anything starts
            request = pickle.dumps({"kind": self.state.kind, "task": self.work}, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as e:  # noqa: BLE001 - pickle raises TypeError, AttributeError, PicklingError...
            raise RuntimeError(f"{self.state.kind}: the job cannot be sent to a worker process: {e}") from e
        with self.state.lock:
            self.state.status, self.state.started = RUNNING, time.monotonic()
        self.process = subprocess.Popen([worker_python(), "-m", "drapelab.ui.worker"], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, env=env, close_fds=True)
        os.set_blocking(self.process.stdout.fileno(), False)
        _track(self)
        try:
            self.process.stdin.write(struct.pack("<I", len(request)) + request)
            self.process.stdin.flush()
        except OSError as e:  # the interpreter did not start (its reason is on the console)
            self.process.kill()
            self.process.wait()
            self._end({"status": FAILED, "error": f"the worker process ({worker_python()}) did not start: {e}"})
        return self

    def run_sync(self):
        return Job(self.state.kind, self.work).run_sync()

    def _end(self, message):
        s = self.state
        with s.lock:
            s.status = message["status"]
            s.error = message.get("error")
            s.result = message.get("result")
            if message.get("message"):
                s.message = message["message"]
            if message.get("fraction") is not None:
                s.fraction = message["fraction"]
            s.traceback = message.get("traceback")
            s.finished = message.get("finished") or time.monotonic()
        self._ended = True

    def poll(self):
        """Reads what the worker reported so far (never blocks); returns True while the job runs."""
        if self.process is None:
            return False
        if self._ended:
            self.process.poll()  # reaps the process once it has exited
            return False
        exited = self.process.poll() is not None
        while True:
            try:
                chunk = self.process.stdout.read()
            except (BlockingIOError, InterruptedError):
                chunk = None
            if not chunk:
                break
            self._buffer += chunk
        while len(self._buffer) >= 4:
            (size,) = struct.unpack("<I", self._buffer[:4])
            if len(self._buffer) < 4 + size:
                break
            message = pickle.loads(self._buffer[4:4 + size])
            self._buffer = self._buffer[4 + size:]
            if message.get("type") == "update":
                self.state.update(message.get("fraction"), message.get("message"), **message.get("metrics", {}))
            elif message.get("type") == "record":
                self.state.record(message["value"])
            elif message.get("type") == "end":
                self._end(message)
        if exited and not self._ended:
            code = self.process.returncode
            status = CANCELLED if self.state.cancel.is_set() else FAILED
            self._end({"status": status, "error": None if status == CANCELLED else
                       f"the worker process ended without a result (exit code {code}; its messages are on "
                       f"Blender's console)"})
        return not self._ended

    def cancel(self):
        self.state.request_cancel()
        if self.process is not None and self.process.poll() is None:
            try:
                self.process.stdin.write(b"c")
                self.process.stdin.flush()
            except (BrokenPipeError, OSError):
                pass

    def join(self, timeout=None):
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() or (self.process is not None and self.process.poll() is None):
            if deadline is not None and time.monotonic() >= deadline:
                return not self.poll()  # the job ended (its process is still closing)
            time.sleep(0.02)
        return True

    def kill(self):
        """Ends the worker process at once (Blender closing with a job that did not stop when asked)."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self.poll()

    @property
    def alive(self):
        return self.poll()


_jobs_lock = threading.Lock()
_jobs = {}  # kind -> the latest Job of that kind


def _track(job):
    with _jobs_lock:
        _jobs[job.state.kind] = job


def current(kind=None):
    """The latest job of `kind` (or the latest running one of any kind), or None. Worker processes' reports
    are read first."""
    with _jobs_lock:
        jobs = list(_jobs.values())
    for j in jobs:
        if isinstance(j, ProcessJob):
            j.poll()
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
    they share the cores); synchronous runs it on this thread, else a Task in a worker process and a plain
    callable on a worker thread. Returns the job."""
    busy = running_jobs()
    if busy:
        raise RuntimeError(f"a {busy[0].state.kind} job is running; cancel it or wait for it to finish")
    job = ProcessJob(kind, work) if isinstance(work, Task) and not synchronous else Job(kind, work)
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
    stuck = [j for j in jobs if not j.join(max(0.0, deadline - time.monotonic()))]
    for j in stuck:
        if isinstance(j, ProcessJob):
            j.kill()
    return [j.state.kind for j in stuck]


def forget_finished():
    """Drops finished jobs (unregister: a re-registered add-on starts with no job)."""
    with _jobs_lock:
        for k in [k for k, j in _jobs.items() if not j.alive and j.state.status != RUNNING]:
            del _jobs[k]


atexit.register(cancel_all, 5.0)
