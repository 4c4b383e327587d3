"""A real Blender window under Xvfb (tests/blender/ui_screenshot.py): the Drape tab drawn while a fit runs and after
one finished, captured as PNGs kept in build/test-artifacts/ (look at them: addon_panel_fit_running.png,
addon_panel_fit_done.png). Checks: Blender exits cleanly, no Python error was printed (a panel's draw error is
printed as a traceback), the pictures are written, full-window size and not blank, and the sidebar area changed
between the running and the finished fit (the panel drew the job's state, then its result)."""
import os
import shutil
import subprocess

import numpy as np
import pytest

from fit_support import ROOT

from drapelab import measure

BLENDER, XVFB = shutil.which("blender"), shutil.which("xvfb-run")
pytestmark = pytest.mark.skipif(BLENDER is None or XVFB is None, reason="needs Blender and xvfb-run")
SCREEN = (1920, 1200)
ARTIFACTS = os.path.join(ROOT, "build", "test-artifacts")


def test_drape_tab_in_a_real_window_during_and_after_a_fit(tmp_path):
    os.makedirs(ARTIFACTS, exist_ok=True)
    env = dict(os.environ, DRAPELAB_ROOT=ROOT, DRAPELAB_NATIVE_DIR=os.path.join(ROOT, "build", "python"),
               OPENBLAS_NUM_THREADS="1", TMPDIR=str(tmp_path))  # the add-on's cache of the unsaved file
    done = subprocess.run([XVFB, "-a", "-s", f"-screen 0 {SCREEN[0]}x{SCREEN[1]}x24", BLENDER, "--factory-startup",
                           "--enable-event-simulate", "--python", os.path.join(ROOT, "tests", "blender", "ui_screenshot.py"),
                           "--", ARTIFACTS], env=env, capture_output=True, text=True, timeout=400)
    log = done.stdout + done.stderr
    crash = tmp_path / "blender.crash.txt"  # Blender's own backtrace when it dies of a signal
    if crash.exists():
        log += "\n== blender.crash.txt\n" + crash.read_text(errors="replace")
    with open(os.path.join(ARTIFACTS, "addon_ui_screenshot.log"), "w") as f:
        f.write(log)
    assert done.returncode == 0 and "UI DONE" in done.stdout, log[-6000:]
    assert "Traceback" not in log and "Error: Python" not in log and "UI FAILED" not in log, log[-4000:]
    assert "job=RUNNING" in done.stdout and "epoch" in done.stdout
    assert "CANCELLED job=CANCELLED" in done.stdout  # Esc stopped the running fit
    shots = {}
    for name in ("addon_panel_fit_running.png", "addon_panel_fit_done.png", "addon_panel_diagnose_garment.png"):
        img, _ = measure.read_image(os.path.join(ARTIFACTS, name))
        img = np.asarray(img)
        assert img.shape == (SCREEN[1], SCREEN[0]), img.shape
        assert img.std() > 0.05, f"{name} looks blank"
        shots[name] = img
    # the 3D view's sidebar (right of the viewport, left of the outliner) differs between the two states
    a, b = (shots[n][:, int(0.68 * SCREEN[0]):int(0.82 * SCREEN[0])] for n in list(shots)[:2])
    assert np.abs(a - b).mean() > 0.01
