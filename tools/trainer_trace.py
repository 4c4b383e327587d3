"""Seeded short fits (homo, heter, bdp on circle1 with the tilt effect fitted; bdp_clip: bdp with a tight
gradient clip, so that clipping acts) and their loss traces, to show that a change of the trainer's numerical
core changes no result (docs/lab/trainer-native.md). The bdp fit writes a checkpoint after epoch 3 (OUT.ckpt.json);
`resume` continues such a checkpoint (e.g. one the old trainer wrote) to epoch 5 and records that trace.

    PYTHONPATH=addon:build/python OPENBLAS_NUM_THREADS=1 /usr/bin/python3 tools/trainer_trace.py run OUT.json
    PYTHONPATH=... /usr/bin/python3 tools/trainer_trace.py resume CHECKPOINT.json OUT.json
    /usr/bin/python3 tools/trainer_trace.py compare BEFORE.json AFTER.json
"""
import json
import os
import sys
import time

MODELS = ("homo", "heter", "bdp", "bdp_clip")
CHECKPOINT_EPOCH = 3
EPOCHS = 5
IMAGE = os.path.join("assets", "cusick", "fabric_02", "silhouettes", "sample_02_capture_1.jpg")
FIELDS = ("loss", "data", "kl", "grad_norm", "clip", "iou", "mse")


def _job(model):
    import copy
    from drapelab import infer
    cfg = copy.deepcopy(infer.load_config())
    cfg["mesh_level"] = 1
    if model == "bdp_clip":  # clipping from epoch 3 on, at 0.3 x the median norm of epochs 1-2
        cfg["gradient_clip"] = {"factor": 0.3, "window": 2, "min_epochs": 2}
    return infer.FitJob([IMAGE], 0.192, model=model.split("_")[0], seed=3, config=cfg, threads=2,
                        effects={"tilt": None})


def _save(result, out):
    with open(out + ".tmp", "w") as f:
        json.dump(result, f, indent=1)
    os.replace(out + ".tmp", out)


def run(out):
    from drapelab import infer
    result = {"module": infer.__file__, "epochs": EPOCHS, "image": IMAGE, "models": {}}
    for model in MODELS:
        t0 = time.monotonic()
        job = _job(model)
        if model == "bdp":
            job.run(epochs=CHECKPOINT_EPOCH, checkpoint=out + ".ckpt.json")
        job.run(epochs=EPOCHS)
        result["models"][model] = {
            "history": [{k: h.get(k) for k in FIELDS + ("effects",)} for h in job.history],
            "theta": {k: v.tolist() for k, v in job.theta.items()},
            "seconds": time.monotonic() - t0}
        print(model, [round(h["loss"], 6) for h in job.history if "loss" in h], f"{time.monotonic() - t0:.1f} s",
              flush=True)
    _save(result, out)


def resume(checkpoint, out):
    """The bdp fit continued from `checkpoint` to EPOCHS: its trace as the "bdp" entry (epochs before the
    checkpoint come from the checkpoint's history)."""
    job = _job("bdp")
    job.load_checkpoint(checkpoint)
    job.run(epochs=EPOCHS)
    _save({"checkpoint": checkpoint, "models": {"bdp": {
        "history": [{k: h.get(k) for k in FIELDS + ("effects",)} for h in job.history],
        "theta": {k: v.tolist() for k, v in job.theta.items()}}}}, out)


def _flat(v):
    if isinstance(v, list):
        return [x for e in v for x in _flat(e)]
    return [v]


def compare(a_path, b_path):
    with open(a_path) as f:
        a = json.load(f)
    with open(b_path) as f:
        b = json.load(f)
    print("| model | epoch | loss before | loss after | max rel. diff (loss, data, kl, grad_norm, clip) |")
    print("|---|---|---|---|---|")
    worst_all = 0.0
    for model in [m for m in MODELS if m in a["models"] and m in b["models"]]:
        ha, hb = a["models"][model]["history"], b["models"][model]["history"]
        assert len(ha) == len(hb), (model, len(ha), len(hb))
        for ea, eb in zip(ha, hb):
            worst = max(abs(ea[k] - eb[k]) / max(abs(ea[k]), 1e-300) for k in ("loss", "data", "kl", "grad_norm", "clip"))
            worst_all = max(worst_all, worst)
            print(f"| {model} | {ha.index(ea) + 1} | {ea['loss']:.12g} | {eb['loss']:.12g} | {worst:.2e} |")
        ta, tb = a["models"][model]["theta"], b["models"][model]["theta"]
        td = max(abs(x - y) / max(abs(x), 1e-300) for k in ta for x, y in zip(_flat(ta[k]), _flat(tb[k])))
        worst_all = max(worst_all, td)
        print(f"| {model} | final theta | | | {td:.2e} |")
    print(f"\nlargest relative difference: {worst_all:.2e}")
    return worst_all


if __name__ == "__main__":
    if sys.argv[1] == "run":
        run(sys.argv[2])
    elif sys.argv[1] == "resume":
        resume(sys.argv[2], sys.argv[3])
    else:
        sys.exit(0 if compare(sys.argv[2], sys.argv[3]) < 1e-9 else 1)
