"""Failure semantics (docs/failures.md): a diverging rollout stops with the state before it, writes are
atomic even when the disk fills mid-write, cancelled jobs keep what is complete, out-of-range numbers are refused
at the boundary naming the field."""
import json
import os
import subprocess
import sys
import threading

import numpy as np
import pytest

from drapelab import cli, infer, sim, tables

from fit_support import ASSET_IMAGE, SHIPPED_PRESET, small_config


# ---------------------------------------------------------------- divergence
def test_a_diverging_rollout_names_the_step_and_keeps_the_state_before_it():
    # Limp fabric with the published strain-softening stretching table: the h = 0.05 s rollout diverges
    # (docs/physics.md); on circle1 with a quarter of Cotton Blue's bending, at step 8.
    model = sim.ClothModel(sim.cusick_specimen(1))
    p = model.parameters(stretch=tables.COTTON_BLUE.stretch, bend=tables.COTTON_BLUE.bend / 4)
    with pytest.raises(sim.SolverError, match=r"rollout: step \d+ diverged") as info:
        model.simulate(p, record=False)
    e = info.value
    assert e.step >= 1 and f"step {e.step} " in str(e)
    assert e.positions.shape == e.velocities.shape == (model.num_vertices, 3)
    assert np.all(np.isfinite(e.positions)) and np.all(np.isfinite(e.velocities))
    assert np.max(np.linalg.norm(e.velocities, axis=1)) <= sim.DEFAULT_MAX_SPEED
    # the attached state is exactly the rollout's state after the steps that completed
    np.testing.assert_array_equal(model.simulate(p, steps=e.step, record=False), e.positions)
    # and the model is not left claiming a rollout to differentiate
    with pytest.raises(sim.InputError, match="run simulate"):
        model.backward(np.ones((model.num_vertices, 3)))


# ---------------------------------------------------------------- atomic writes
WRITER = r"""
import resource, signal, sys
import numpy as np
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG, like a full disk
from drapelab import infer, measure, sim
kind, path, limit = sys.argv[1], sys.argv[2], int(sys.argv[3])
rng = np.random.default_rng(0)
model = sim.ClothModel(sim.cusick_specimen(3)) if kind == "obj" else None
preset = infer.load_preset(sys.argv[4]) if kind == "preset" else None
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
try:
    if kind == "json":
        measure.write_json(path, {"x": list(range(100000))})
    elif kind == "preset":
        infer.write_preset(path, preset)
    elif kind == "image":
        measure.write_image(path, rng.random((512, 512)))
    elif kind == "overlay":
        measure.write_overlay(path, rng.random((256, 256)), rng.random((256, 256)))
    elif kind == "obj":
        sim.write_obj(path, model.rest_positions, model.faces)
except Exception as e:
    print(type(e).__name__, e)
    sys.exit(3)
"""


@pytest.mark.parametrize("kind, name", [("json", "out.json"), ("preset", "preset.json"), ("image", "mask.png"),
                                        ("image", "mask.tif"), ("image", "mask.exr"), ("overlay", "overlay.png"),
                                        ("obj", "drape.obj")])
def test_a_write_that_fails_midway_leaves_the_old_file_and_no_partial_file(tmp_path, kind, name):
    # The writer runs in a child process whose file size limit (4 KB, below every payload) makes the write fail
    # part way, as a full disk does.
    out = tmp_path / name
    out.write_bytes(b"the old file\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    r = subprocess.run([sys.executable, "-c", WRITER, kind, str(out), "4096", SHIPPED_PRESET], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 3, r.stdout + r.stderr
    assert str(out) in r.stdout  # the error names the file
    assert out.read_bytes() == b"the old file\n"
    assert os.listdir(tmp_path) == [name]  # no temporary file left behind


# ---------------------------------------------------------------- cancel
def test_a_fit_cancelled_during_calibration_keeps_its_checkpoint_and_the_old_preset(tmp_path):
    out = tmp_path / "p.json"
    out.write_text("old preset\n")
    ckpt = str(tmp_path / "p.ckpt")
    cancel = threading.Event()
    seen = []

    def calibration_progress(c):
        seen.append(c["evaluation"])
        cancel.set()

    with pytest.raises(infer.Cancelled):
        infer.fit([ASSET_IMAGE], 0.192, model="bdp", epochs=2, checkpoint=ckpt, out=str(out), cancel_event=cancel,
                  calibration_progress=calibration_progress, config=small_config(), threads=1)
    assert seen == [1]  # stopped at the calibration's next draw, not after it
    assert out.read_text() == "old preset\n"
    assert sorted(os.listdir(tmp_path)) == ["p.ckpt", "p.json"]
    job = infer.FitJob([ASSET_IMAGE], 0.192, model="bdp", config=small_config(), threads=1)
    job.load_checkpoint(ckpt)
    assert job.epoch == 2


def test_a_cancelled_evaluation_raises_and_writes_nothing(tmp_path):
    cancel = threading.Event()
    done = []

    def progress(k, n):
        done.append(k)
        cancel.set()

    with pytest.raises(infer.Cancelled):
        infer.evaluate(SHIPPED_PRESET, [ASSET_IMAGE], samples=20, threads=1, mesh_level=1, progress=progress,
                       cancel_event=cancel)
    assert done == [1]


def test_evaluate_command_stops_on_ctrl_c_with_status_130_and_no_output(tmp_path):
    out = tmp_path / "eval.json"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "drapelab.cli", "evaluate", "--preset", SHIPPED_PRESET,
                             "--images", ASSET_IMAGE, "--samples", "40", "--threads", "1", "--json", str(out)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline()  # "sample 4/40": the evaluation is under way
    proc.send_signal(2)
    stdout, stderr = proc.communicate(timeout=120)
    assert first.startswith("sample ")
    assert proc.returncode == 130, stderr
    assert "cancelled" in stderr and not out.exists()


# ---------------------------------------------------------------- out-of-range numbers
@pytest.mark.parametrize("density", [0.0, -0.2, float("nan"), float("inf"), "heavy", None])
def test_density_out_of_range_is_refused_naming_it(density):
    with pytest.raises(infer.InputError, match="density"):
        infer.fit([ASSET_IMAGE], density, model="homo", epochs=1, config=small_config())


def _preset_with(tmp_path, edit):
    preset = json.load(open(SHIPPED_PRESET))
    edit(preset)
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(preset))
    return str(path)


@pytest.mark.parametrize("edit, field", [
    (lambda p: p.update(density_kg_m2=-0.1), "density_kg_m2"),
    (lambda p: p.update(density_kg_m2=0), "density_kg_m2"),
    (lambda p: p["stretch_N_m"][0].__setitem__(0, -5.0), "stretch_N_m"),
    (lambda p: p["stretch_N_m"][2].__setitem__(3, float("nan")), "stretch_N_m"),
    (lambda p: p["posterior"]["bend"]["log_mean"][1].__setitem__(2, float("nan")), "log_mean"),
    (lambda p: p["posterior"]["bend"]["log_std"][0].__setitem__(0, -0.1), "log_std"),
    (lambda p: p["posterior"]["bend"].update(global_log_std=-1), "global_log_std"),
    (lambda p: p["placement_noise"].update(velocity_m_s=-0.05), "velocity_m_s"),
])
def test_a_preset_with_numbers_out_of_range_is_refused_naming_the_file_and_field(tmp_path, edit, field):
    path = _preset_with(tmp_path, edit)
    with pytest.raises(infer.InputError, match=field) as info:
        infer.load_preset(path)
    assert path in str(info.value)


def test_a_negative_poisson_coupling_in_a_preset_is_allowed(tmp_path):
    # c12 (column 1) may be negative (auxetic weaves); every other stretching entry may not
    path = _preset_with(tmp_path, lambda p: p["stretch_N_m"][0].__setitem__(1, -1.0))
    assert infer.load_preset(path)["stretch_N_m"][0][1] == -1.0


@pytest.mark.parametrize("kwargs, field", [
    ({"time_budget": -5}, "time_budget"), ({"time_budget": 0}, "time_budget"),
    ({"time_budget": float("nan")}, "time_budget"), ({"time_budget": float("inf")}, "time_budget"),
    ({"epochs": 0}, "epochs"), ({"threads": 0}, "threads"), ({"threads": -2}, "threads"), ({"seed": -1}, "seed"),
])
def test_fit_arguments_out_of_range_are_refused_before_any_work(kwargs, field):
    args = dict(model="homo", config=small_config())
    args.update(kwargs)
    with pytest.raises(infer.InputError, match=field):
        infer.fit([ASSET_IMAGE], 0.192, **args)


@pytest.mark.parametrize("kwargs, field", [({"samples": 0}, "samples"), ({"threads": -1}, "threads"),
                                           ({"seed": -3}, "seed")])
def test_evaluate_arguments_out_of_range_are_refused(kwargs, field):
    with pytest.raises(infer.InputError, match=field):
        infer.evaluate(SHIPPED_PRESET, [ASSET_IMAGE], **kwargs)


@pytest.mark.parametrize("argv, field", [
    (["--density", "-0.192"], "density"), (["--density", "nan"], "density"),
    (["--density", "0.192", "--time-budget", "-60"], "time_budget"),
    (["--density", "0.192", "--time-budget", "nan"], "time_budget"),
    (["--density", "0.192", "--threads", "0"], "threads"),
])
def test_fit_command_refuses_numbers_out_of_range_with_status_2(tmp_path, capsys, argv, field):
    out = tmp_path / "p.json"
    status = cli.main(["fit", "--images", ASSET_IMAGE, "--out", str(out), "--model", "homo"] + argv)
    err = capsys.readouterr().err
    assert status == 2 and f"drapelab fit: error: {field}" in err
    assert os.listdir(tmp_path) == []
