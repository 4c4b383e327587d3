"""The add-on's bpy-free parts: the job worker and its shared state (drapelab.ui.jobs), the fit and diagnose jobs
(drapelab.ui.tasks) with cancel latency measured on a real fit, the pictures (drapelab.ui.figures) and the preset
files (drapelab.ui.presets). None of them may import bpy."""
import json
import os
import shutil
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from fit_support import ASSET_IMAGE, ROOT, SHIPPED_PRESET

from drapelab import infer
from drapelab.ui import figures, jobs, presets, tasks

CANCEL_LIMIT_S = 1.0  # the bound: Cancel takes effect within a second


@pytest.fixture(autouse=True)
def no_job_left():
    yield
    assert not jobs.cancel_all(timeout=20.0), "a worker did not stop"
    jobs.forget_finished()


def test_ui_helpers_do_not_import_bpy():
    assert "bpy" not in sys.modules
    env = dict(os.environ, PYTHONPATH=f"{ROOT}/addon:{ROOT}/build/python")
    code = ("import sys, drapelab.cli, drapelab.ui.jobs, drapelab.ui.tasks, drapelab.ui.figures, drapelab.ui.presets; "
            "import drapelab; assert callable(drapelab.register); assert 'bpy' not in sys.modules, 'bpy imported'")
    subprocess.run([sys.executable, "-c", code], check=True, env=env)
    out = subprocess.run([sys.executable, "-m", "drapelab.cli", "--help"], env=env, capture_output=True, text=True)
    assert out.returncode == 0 and "fit" in out.stdout


def test_job_result_progress_and_history_on_a_worker_thread():
    seen = threading.Event()

    def work(state):
        for i in range(5):
            state.update((i + 1) / 5, f"step {i}", loss=1.0 / (i + 1))
            state.record(1.0 / (i + 1))
        seen.wait(5)
        return {"answer": 42}

    job = jobs.start("unit", work)
    assert job.alive and jobs.current() is job
    with pytest.raises(RuntimeError, match="unit job is running"):
        jobs.start("other", lambda s: None)
    seen.set()
    assert job.join(5)
    snap = job.state.snapshot()
    assert snap["status"] == jobs.DONE and job.state.result == {"answer": 42}
    assert snap["fraction"] == 1.0 and snap["history"] == [1.0, 0.5, 1 / 3, 0.25, 0.2]
    assert snap["metrics"]["loss"] == pytest.approx(0.2) and snap["message"] == "step 4"


def test_job_error_and_cancel_states():
    job = jobs.start("bad", lambda s: (_ for _ in ()).throw(ValueError("density: must be > 0")), synchronous=True)
    assert job.state.status == jobs.FAILED and job.state.error == "density: must be > 0"

    def waits(state):
        while not state.cancel.wait(0.01):
            pass
        raise infer.Cancelled()
    job = jobs.start("waits", waits)
    t = time.monotonic()
    job.cancel()
    assert job.join(5) and job.state.status == jobs.CANCELLED and time.monotonic() - t < 1.0


def test_bad_fit_arguments_fail_before_a_worker_starts(tmp_path):
    with pytest.raises(infer.InputError, match="images"):
        tasks.fit_work([], 0.2, str(tmp_path))
    with pytest.raises(infer.InputError, match="density"):
        tasks.fit_work([ASSET_IMAGE], -1.0, str(tmp_path))
    with pytest.raises(infer.InputError, match="no such file"):
        tasks.fit_work([str(tmp_path / "missing.jpg")], 0.2, str(tmp_path))
    with pytest.raises(infer.InputError, match="preset"):
        tasks.diagnose_work("", [ASSET_IMAGE], str(tmp_path))
    with pytest.raises(infer.InputError, match="samples"):
        tasks.diagnose_work(SHIPPED_PRESET, [ASSET_IMAGE], str(tmp_path), samples=2)


def _cancel_delay(work, after_s, until=None):
    """Starts the job, waits after_s seconds (and, with `until`, until its message starts with it), cancels it
    and returns (seconds from the cancel request to the worker's end, status, message at the cancel)."""
    job = jobs.start("fit", work)
    time.sleep(after_s)
    deadline = time.monotonic() + 120
    while until and not job.state.snapshot()["message"].startswith(until) and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)  # inside the next drape or backward
    assert job.alive, "the job ended before the cancel: make it longer"
    message = job.state.snapshot()["message"]
    t = time.monotonic()
    job.cancel()
    assert job.join(20)
    return time.monotonic() - t, job.state.status, message


def test_cancel_stops_a_running_fit_within_a_second_and_keeps_the_last_preset(tmp_path):
    """A homo fit on circle2 (drapes of ~0.7 s): cancelled once in its scale search and once in its epochs."""
    out = str(tmp_path)
    preset_path = os.path.join(out, "presets", "fit_homo.json")
    os.makedirs(os.path.dirname(preset_path))
    with open(SHIPPED_PRESET) as f:
        old = f.read()
    with open(preset_path, "w") as f:  # an earlier result the cancelled fit must leave as it was
        f.write(old)
    delays = []
    for after, until in ((1.0, None), (0.0, "epoch")):
        work = tasks.fit_work([ASSET_IMAGE], 0.192, out, model="homo", epochs=200, mesh_level=2, calibrate=False)
        delay, status, message = _cancel_delay(work, after, until)
        print(f"cancel after {after} s ({message}): stopped in {1000 * delay:.0f} ms")
        delays.append(delay)
        assert status == jobs.CANCELLED
    assert max(delays) < CANCEL_LIMIT_S, delays
    with open(preset_path) as f:
        assert f.read() == old
    assert not [n for n in os.listdir(os.path.dirname(preset_path)) if n.startswith(".tmp")]


def test_fit_job_writes_preset_overlay_rtheta_and_metrics(tmp_path):
    work = tasks.fit_work([ASSET_IMAGE], 0.192, str(tmp_path), model="homo", epochs=1, mesh_level=1,
                          fabric={"name": "Cotton Blue"}, calibrate=False)
    state = jobs.start("fit", work, synchronous=True).state
    assert state.status == jobs.DONE, state.error
    r = state.result
    assert r["preset"].endswith("Cotton_Blue_homo.json")
    p = infer.load_preset(r["preset"])
    assert p["model"] == "homo" and p["fabric"]["name"] == "Cotton Blue" and p["training"]["epochs"] == 1
    assert state.history and state.metrics["epoch"] == 1
    m = r["metrics"]
    assert 0.5 < m["iou"] <= 1.0 and 0 <= m["mse"] < 0.5 and m["mesh_level"] == 1
    assert m["drape_coefficient"]["observed"] == pytest.approx(0.670, abs=0.01)
    for png in (r["overlay"], r["rtheta"]):
        assert open(png, "rb").read(8) == b"\x89PNG\r\n\x1a\n" and os.path.getsize(png) > 5000


def test_figures_measurement_preview_and_history_chart(tmp_path):
    png = str(tmp_path / "m.png")
    m = figures.measurement_preview(ASSET_IMAGE, png)
    assert m["drape_coefficient"] == pytest.approx(0.670, abs=0.01) and m["node_count"] >= 6
    from drapelab import measure
    img, _ = measure.read_image(png)
    img = np.asarray(img)
    assert img.std() > 0.1  # the photo, not a blank page
    with pytest.raises(infer.InputError):
        bad = tmp_path / "bad.jpg"
        bad.write_bytes(b"not an image")
        figures.measurement_preview(str(bad), str(tmp_path / "bad.png"))
    assert not (tmp_path / "bad.png").exists()
    chart = str(tmp_path / "h.png")
    figures.history_chart([{"model": "homo", "mse": 0.07}, {"model": "bdp", "mse": 0.04, "dc_error": 0.03},
                           {"model": "no mse", "mse": None}], chart)
    assert os.path.getsize(chart) > 3000
    with pytest.raises(ValueError, match="no entry"):
        figures.history_chart([{"model": "x"}], str(tmp_path / "none.png"))


def test_preset_files_save_import_resolve_delete(tmp_path):
    user = str(tmp_path / "user")
    entries = presets.list_presets(user)
    assert len([e for e in entries if e["source"] == presets.SHIPPED]) >= 15
    saved = presets.save(SHIPPED_PRESET, user, "my cotton/blue")
    assert os.path.basename(saved) == "my_cotton_blue.json"
    assert infer.load_preset(saved)["posterior"] == infer.load_preset(SHIPPED_PRESET)["posterior"]
    assert presets.resolve("my_cotton_blue", user) == saved
    assert presets.resolve("fabric_05_wool_red_bdp", user).endswith("fabric_05_wool_red_bdp.json")
    with pytest.raises(infer.InputError, match="known"):
        presets.resolve("no such preset", user)
    assert presets.resolve("fabric_05", user).endswith("fabric_05_wool_red_bdp.json")  # a unique prefix
    with pytest.raises(infer.InputError, match="start of several"):
        presets.resolve("fabric_1", user)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"kind": "drapelab-material-preset", "schema_version": 99}))
    with pytest.raises(infer.InputError, match="newer"):
        presets.import_file(str(bad), user)
    exported = presets.write_to(saved, str(tmp_path / "export.json"))
    imported = presets.import_file(exported, user)
    assert os.path.basename(imported) == "export.json"
    with pytest.raises(infer.InputError, match="shipped"):
        presets.delete(presets.resolve("fabric_05_wool_red_bdp", user), user)
    presets.delete(saved, user)
    assert not os.path.exists(saved) and os.path.exists(SHIPPED_PRESET)


def test_cancel_stops_a_running_diagnosis_within_a_second(tmp_path):
    """The shipped preset's draws on circle3 with backward (about a second each): cancelled mid-draw."""
    work = tasks.diagnose_work(SHIPPED_PRESET, [ASSET_IMAGE], str(tmp_path), samples=8, time_budget=300)
    job = jobs.start("diagnose", work)
    time.sleep(4.0)
    assert job.alive
    t = time.monotonic()
    job.cancel()
    assert job.join(20)
    delay = time.monotonic() - t
    print(f"diagnose cancelled after 4 s: stopped in {1000 * delay:.0f} ms ({job.state.snapshot()['message']})")
    assert delay < CANCEL_LIMIT_S
    assert job.state.status == jobs.DONE and job.state.result["diagnosis"]["cancelled"]  # what was done is kept


BLENDER_EXIT_SCRIPT = r'''
import os, sys, time
sys.path[:0] = [os.path.join(os.environ["DRAPELAB_ROOT"], "addon"), os.environ["DRAPELAB_NATIVE_DIR"]]
import bpy, drapelab
drapelab.register()
from drapelab.ui import jobs, tasks
image = os.path.join(os.environ["DRAPELAB_ROOT"], "assets", "cusick", "fabric_02", "silhouettes", "sample_02_capture_1.jpg")
work = tasks.fit_work([image], 0.192, sys.argv[-1], model="homo", epochs=500, mesh_level=2, calibrate=False)

def logged(state):
    try:
        return work(state)
    finally:
        print(f"WORKER ENDED cancel={state.cancel.is_set()} at {time.time():.3f}", flush=True)

job = jobs.start("fit", logged)
time.sleep(2.0)
assert job.alive
print(f"QUITTING at {time.time():.3f}", flush=True)
bpy.ops.wm.quit_blender()
'''


@pytest.mark.skipif(not shutil.which("blender"), reason="needs Blender")
def test_quitting_blender_stops_a_running_job(tmp_path):
    script = tmp_path / "quit.py"
    script.write_text(BLENDER_EXIT_SCRIPT)
    env = dict(os.environ, DRAPELAB_ROOT=ROOT, DRAPELAB_NATIVE_DIR=os.path.join(ROOT, "build", "python"),
               TMPDIR=str(tmp_path))
    t = time.monotonic()
    done = subprocess.run(["blender", "--background", "--factory-startup", "--python", str(script), "--",
                           str(tmp_path)], env=env, capture_output=True, text=True, timeout=120)
    elapsed = time.monotonic() - t
    out = done.stdout
    assert "QUITTING" in out and "WORKER ENDED cancel=True" in out, out[-2000:] + done.stderr[-2000:]
    quit_at = float(out.split("QUITTING at ")[1].split()[0])
    ended_at = float(out.split("WORKER ENDED cancel=True at ")[1].split()[0])
    print(f"Blender quit mid-fit: the worker ended {1000 * (ended_at - quit_at):.0f} ms after the quit; "
          f"whole run {elapsed:.1f} s")
    assert ended_at - quit_at < 2.0
