"""The worker process of the add-on's background jobs (bpy-free): `python -m drapelab.ui.worker`.

Started by drapelab.ui.jobs.ProcessJob. Reads one length-prefixed pickle from stdin ({"kind", "task"}: a
jobs.Task, rebuilt here from its factory and arguments), runs it with a JobState whose reports go back on
stdout as length-prefixed pickles ("update", "record", then one "end" with status, result, error), and reads
stdin for the rest of its life: any byte (or the pipe closing: Blender went away) sets the cancel flag, which
the work checks between simulation steps. Anything the work prints goes to stderr (Blender's console), so stdout
carries only the reports.
"""
import os
import pickle
import struct
import sys
import threading
import time

from . import jobs


def _read_exact(stream, n):
    data = b""
    while len(data) < n:
        chunk = stream.read(n - len(data))
        if not chunk:
            raise EOFError("the add-on closed the pipe before sending the job")
        data += chunk
    return data


class _ReportingState(jobs.JobState):
    """A JobState that also sends every update to the add-on."""

    def __init__(self, kind, out):
        super().__init__(kind)
        self._out, self._out_lock = out, threading.Lock()

    def _send(self, message):
        with self._out_lock:
            try:
                jobs.write_message(self._out, message)
            except (BrokenPipeError, OSError):  # the add-on is gone: stop the work
                self.cancel.set()

    def update(self, fraction=None, message=None, **metrics):
        super().update(fraction, message, **metrics)
        self._send({"type": "update", "fraction": fraction, "message": message, "metrics": metrics})

    def record(self, value):
        super().record(value)
        self._send({"type": "record", "value": float(value)})


def _watch_cancel(stdin, state):
    try:
        stdin.read(1)  # a byte: Cancel; EOF: the add-on (Blender) is gone
    except (OSError, ValueError):
        pass
    state.request_cancel()


def main():
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # prints of the work go to stderr
    sys.stdout = sys.stderr
    stdin = sys.stdin.buffer
    (size,) = struct.unpack("<I", _read_exact(stdin, 4))
    try:
        request = pickle.loads(_read_exact(stdin, size))  # rebuilding the Task checks its arguments again
    except Exception as e:  # noqa: BLE001 - reported to the add-on, which shows it
        jobs.write_message(out, {"type": "end", "status": jobs.FAILED, "error": str(e) or type(e).__name__,
                                 "finished": time.monotonic()})
        return
    state = _ReportingState(request["kind"], out)
    job = jobs.Job(request["kind"], request["task"])
    job.state = state
    threading.Thread(target=_watch_cancel, args=(stdin, state), daemon=True).start()
    job._run()
    end = {"type": "end", "status": state.status, "error": state.error, "message": state.message,
           "fraction": state.fraction, "traceback": getattr(state, "traceback", None),
           "finished": state.finished or time.monotonic()}
    try:
        pickle.dumps(state.result)
        end["result"] = state.result
    except Exception as e:  # noqa: BLE001 - a result that cannot travel is a failure the UI must show
        end.update(status=jobs.FAILED, error=f"the job's result could not be sent back: {e}")
    with state._out_lock:
        jobs.write_message(out, end)
    out.close()


if __name__ == "__main__":
    main()
