"""Where in 3D a model's drapes differ from measured ones: fold shape per material ring and hinge angles per band.

A measured drape mesh that shares the model's topology (the Cusick dataset's reconstructions are circle3's mesh,
../shared/data/cusick/README.md) gives every vertex as a known point of the flat specimen, as the model's drapes
do. Per material ring (the vertices whose rest radius lies within RING_HALF_WIDTH of r0): the mean height z, the
mean horizontal radius R, the fold amplitude (half the peak-to-trough of the radial move R - r0 over the rest angle,
smoothed to its first HARMONICS harmonics) and the fold count (maxima of that profile). Per band of rest radius,
the bending edges' dihedral angles (95th / 99th percentile, degrees) of the edges that run radially (their angle
is the hoop curvature: the folds' crests and troughs) and of those along the hoop (the radial curvature: the fall
over the support's edge). Measured in docs/lab/fold-depth.md (tools/fold_geometry.py runs it on the dataset).
"""
import math

import numpy as np

__all__ = ["ring_stats", "summarise", "compare", "dihedral_angles", "features", "feature_names", "RINGS", "BANDS",
           "RECONSTRUCTION_NOISE_M"]

RINGS = tuple(np.round(np.arange(0.095, 0.1451, 0.01), 4))  # ring centres r0 [m] of a 30 cm specimen on an 18 cm disk
RING_HALF_WIDTH = 0.005  # m
BANDS = ((0.09, 0.10), (0.10, 0.12), (0.12, 0.14), (0.14, 0.151))  # rest-radius bands of the hinge statistics [m]
HARMONICS = 16
RADIAL_COS, HOOP_COS = 0.8, 0.35  # an edge is radial when |cos| to the radius exceeds 0.8, along the hoop below 0.35
# The dataset's reconstructions carry vertex noise of about this sd: with it added to the model's drapes, their
# angles along the hoop in the hanging skirt match the real meshes' (4-7 degrees at the 95th percentile, fabric 4;
# docs/lab/fold-depth.md). The angle comparison adds it to the model's drapes (seeded), not to the measured ones.
RECONSTRUCTION_NOISE_M = 0.12e-3
CREST_BANDS = (2, 3)  # the hanging skirt's bands (r0 12-15 cm), where the folds' crests are compared
EDGE_BAND = 0  # r0 9-10 cm: the fall over the support's edge


def smooth_profile(phi, values, harmonics=HARMONICS, samples=720):
    """values(phi) on a regular grid of `samples` angles in [-pi, pi) from a least-squares Fourier fit up to
    `harmonics`."""
    cols = [np.ones_like(phi)]
    for k in range(1, harmonics + 1):
        cols += [np.cos(k * phi), np.sin(k * phi)]
    coef, *_ = np.linalg.lstsq(np.stack(cols, 1), values, rcond=None)
    grid = np.linspace(-np.pi, np.pi, samples, endpoint=False)
    out = coef[0] * np.ones_like(grid)
    for k in range(1, harmonics + 1):
        out += coef[2 * k - 1] * np.cos(k * grid) + coef[2 * k] * np.sin(k * grid)
    return out


def peaks(profile):
    """Indices of the local maxima and minima of a periodic profile."""
    prev, nxt = np.roll(profile, 1), np.roll(profile, -1)
    return np.flatnonzero((profile > prev) & (profile >= nxt)), np.flatnonzero((profile < prev) & (profile <= nxt))


def dihedral_angles(x, edges):
    """Dihedral angles (rad) of bending edges (a, b, c, d), the bend term's formula: 0 flat, magnitude the fold."""
    a, b, c, d = (x[edges[:, i]] for i in range(4))
    e, ec, ed = b - a, c - a, d - a
    n1, n2 = np.cross(e, ec), np.cross(ed, e)
    m = np.cross(n1, n2)
    s = np.einsum("ij,ij->i", m, e) / np.linalg.norm(e, axis=1)
    return np.arctan2(s, np.einsum("ij,ij->i", n1, n2))


def hinge_classes(rest, edges):
    """Per bending edge: its rest midpoint's radius, and whether it runs radially or along the hoop."""
    mid = 0.5 * (rest[edges[:, 0], :2] + rest[edges[:, 1], :2])
    r = np.hypot(mid[:, 0], mid[:, 1])
    d = rest[edges[:, 1], :2] - rest[edges[:, 0], :2]
    c = np.abs(np.einsum("ij,ij->i", d / np.linalg.norm(d, axis=1)[:, None], mid / np.maximum(r, 1e-12)[:, None]))
    return r, c > RADIAL_COS, c < HOOP_COS


def ring_stats(x, rest, edges):
    """One drape x (V, 3) of the specimen with rest positions `rest` (V, 3) and bending edges (E, 4): per ring
    {r0, z, R, amplitude, folds} [m], per band {r0: [lo, hi], crest_p95, crest_p99, hoop_p95} [degrees]."""
    return {"rings": rings_of(x, rest), "bands": bands_of(x, rest, edges)}


def rings_of(x, rest):
    """ring_stats' rings: per material ring {r0, z, R, amplitude, folds} (None where a coarse mesh has too few
    vertices for the profile)."""
    x, rest = np.asarray(x, dtype=float), np.asarray(rest, dtype=float)
    r0 = np.hypot(rest[:, 0], rest[:, 1])
    phi0 = np.arctan2(rest[:, 1], rest[:, 0])
    R = np.hypot(x[:, 0], x[:, 1])
    out = []
    for c in RINGS:
        sel = np.abs(r0 - c) <= RING_HALF_WIDTH
        if sel.sum() < 2 * HARMONICS + 1:  # too few vertices for the profile (a coarse mesh): not measured
            out.append({"r0": float(c), "z": None, "R": None, "amplitude": None, "folds": None})
            continue
        prof = smooth_profile(phi0[sel], R[sel] - r0[sel])  # the radial move: the band's own width is no fold
        hi, lo = peaks(prof)
        amp = 0.5 * (prof[hi].mean() - prof[lo].mean()) if len(hi) and len(lo) else 0.0
        out.append({"r0": float(c), "z": float(x[sel, 2].mean()), "R": float(R[sel].mean()),
                    "amplitude": float(amp), "folds": int(len(hi))})
    return out


def bands_of(x, rest, edges):
    """ring_stats' bands: per band of rest radius the crest and hoop hinge angle percentiles [degrees] (None where
    a coarse mesh has no such hinge in the band)."""
    x, rest = np.asarray(x, dtype=float), np.asarray(rest, dtype=float)
    r, radial, hoop = hinge_classes(rest, edges)
    ang = np.abs(np.degrees(dihedral_angles(x, edges)))

    def pct(sel, q):
        return float(np.percentile(ang[sel], q)) if sel.any() else None

    out = []
    for lo, hi in BANDS:
        band = (r >= lo) & (r < hi)
        out.append({"r0": [lo, hi], "crest_p95": pct(band & radial, 95), "crest_p99": pct(band & radial, 99),
                    "hoop_p95": pct(band & hoop, 95)})
    return out


RING_KEYS = ("z", "R", "amplitude", "folds")
BAND_KEYS = ("crest_p95", "crest_p99", "hoop_p95")


FEATURE_RING_KEYS = ("z", "amplitude")  # the rings' quantities in a drape's feature vector (features)


def feature_names():
    """The names of features()' entries, in order: "band r0 lo-hi cm: key", then "ring r0 cm: key"."""
    return ([f"band {100 * lo:.0f}-{100 * hi:.0f} cm: {key}" for lo, hi in BANDS for key in BAND_KEYS]
            + [f"ring {100 * c:.1f} cm: {key}" for c in RINGS for key in FEATURE_RING_KEYS])


def features(x, rest, edges, noise_m=0.0, rng=None):
    """One drape's 3D fold features as a vector (feature_names' order; NaN where a coarse mesh does not measure
    one): per band the crest and hoop hinge angles' percentiles [degrees], taken with `noise_m` of vertex noise
    (drawn from `rng`) added to x, as compare does for the model's drapes; per ring the mean height z and the fold
    amplitude [m] of x as it is. The diagnosis' 3D step test compares drapes by these (drapelab.diagnose)."""
    x = np.asarray(x, dtype=float)
    noisy = x + rng.normal(0.0, noise_m, x.shape) if noise_m > 0 else x
    values = ([b[key] for b in bands_of(noisy, rest, edges) for key in BAND_KEYS]
              + [r[key] for r in rings_of(x, rest) for key in FEATURE_RING_KEYS])
    return np.array([np.nan if v is None else v for v in values], dtype=float)


def summarise(stats):
    """Mean and sd (ddof 1) over drapes of every ring and band quantity: {rings: [{r0, key: [mean, sd]}], bands}
    (circle3 and finer: every ring and band measured)."""
    out = {"rings": [], "bands": []}
    for group, keys in (("rings", RING_KEYS), ("bands", BAND_KEYS)):
        for i, first in enumerate(stats[0][group]):
            row = {"r0": first["r0"]}
            for key in keys:
                v = np.array([s[group][i][key] for s in stats], dtype=float)
                row[key] = [float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0]
            out[group].append(row)
    return out


def _quantity(measured, model):
    """{measured, model, interval90} from per-drape values (None where not measured: then all None)."""
    if any(v is None for v in measured) or any(v is None for v in model):
        return {"measured": None, "model": None, "interval90": None}
    return {"measured": float(np.mean(measured)), "model": float(np.mean(model)),
            "interval90": [float(v) for v in np.percentile(np.asarray(model, dtype=float), [5, 95])]}


def compare(measured, drapes, rest, edges, noise_m=RECONSTRUCTION_NOISE_M, seed=0):
    """The measured meshes' positions (list of (V, 3)) against the model's drapes (list of (V, 3)) of the specimen
    (rest, edges). Per ring and band: the measured mean, the model's mean and 90 % interval over its drapes (the
    angles with `noise_m` of vertex noise added to the drapes, for the reconstructions' own noise), and `words`:
    a plain sentence for each measured mean outside the model's interval (the folds' crests, the fall over the
    support's edge, where the cloth lies and how deep its folds are), the largest differences first."""
    if not measured or not drapes:
        raise ValueError("fold_geometry.compare: needs at least one measured mesh and one drape")
    rng = np.random.default_rng([int(seed), 7])
    meas = [ring_stats(x, rest, edges) for x in measured]
    model = [rings_of(x, rest) for x in drapes]  # the rings from the drapes as they are, the angles with the noise
    noisy = [bands_of(np.asarray(x) + rng.normal(0.0, noise_m, np.shape(x)), rest, edges) for x in drapes]
    out = {"noise_m": float(noise_m), "measured_meshes": len(measured), "drapes": len(drapes), "rings": [],
           "bands": []}
    for i, c in enumerate(RINGS):
        row = {"r0_m": float(c)}
        for key in RING_KEYS:
            row[key] = _quantity([s["rings"][i][key] for s in meas], [s[i][key] for s in model])
        out["rings"].append(row)
    for i, (lo, hi) in enumerate(BANDS):
        row = {"r0_m": [lo, hi]}
        for key in BAND_KEYS:
            row[key] = _quantity([s["bands"][i][key] for s in meas], [s[i][key] for s in noisy])
        out["bands"].append(row)
    out["words"] = _words(out)
    return out


def _outside(q):
    if q["interval90"] is None:
        return False
    lo, hi = q["interval90"]
    return q["measured"] < lo or q["measured"] > hi


# The effect that moves crest sharpness and the turn over the edge together (docs/physics.md#high_curvature_bending;
# fabric 4 at log_factor -0.9, re-calibrated: crest p99 17 -> 27 degrees, real 29; edge turn 25 -> 40, real 38).
_CURVATURE_HINT = {
    "sharper": "Softer bending in sharp folds does this: high_curvature_bending with log_factor < 0 (set it: one "
               "photo's silhouette does not fit it).",
    "blunter": "Stiffer bending in sharp folds does this: high_curvature_bending with log_factor > 0.",
}


def _words(g):
    found = []  # (weight, sentence)
    crest = [g["bands"][i] for i in CREST_BANDS if g["bands"][i]["crest_p99"]["measured"] is not None]
    worst = max(crest, default=None, key=lambda b: abs(math.log(max(b["crest_p99"]["measured"], 1e-9) /
                                                                max(b["crest_p99"]["model"], 1e-9))))
    q = worst["crest_p99"] if worst else {"interval90": None}
    if _outside(q):
        way = "sharper" if q["measured"] > q["model"] else "blunter"
        found.append((abs(math.log(q["measured"] / max(q["model"], 1e-9))),
                      f"The measured folds' crests are {way} than the model's: 99th percentile of the crest hinges' "
                      f"angles {q['measured']:.0f} degrees at r0 {100 * worst['r0_m'][0]:.0f}-"
                      f"{100 * worst['r0_m'][1]:.0f} cm against the model's {q['model']:.0f} (90 % of drapes "
                      f"{q['interval90'][0]:.0f}-{q['interval90'][1]:.0f}). " + _CURVATURE_HINT[way]))
    q = g["bands"][EDGE_BAND]["hoop_p95"]
    if _outside(q):
        way = "more sharply" if q["measured"] > q["model"] else "more gently"
        found.append((abs(math.log(q["measured"] / max(q["model"], 1e-9))),
                      f"The measured cloth turns down over the support's edge {way} than the model's: 95th percentile "
                      f"of the hinge angles across the fall {q['measured']:.0f} degrees at r0 9-10 cm against "
                      f"{q['model']:.0f} ({q['interval90'][0]:.0f}-{q['interval90'][1]:.0f}). "
                      + _CURVATURE_HINT["sharper" if q["measured"] > q["model"] else "blunter"]))
    hem = g["rings"][-1]
    q = hem["amplitude"]
    if _outside(q):
        way = "deeper" if q["measured"] > q["model"] else "shallower"
        found.append((abs(math.log(max(q["measured"], 1e-9) / max(q["model"], 1e-9))),
                      f"In 3D the measured folds at the hem (r0 {100 * hem['r0_m']:.1f} cm) are {way}: amplitude "
                      f"{1000 * q['measured']:.1f} mm against {1000 * q['model']:.1f} ({1000 * q['interval90'][0]:.1f}-"
                      f"{1000 * q['interval90'][1]:.1f})."))
    moved = [(r, r["R"]) for r in g["rings"] if _outside(r["R"])]
    if moved:
        r, q = max(moved, key=lambda t: abs(t[1]["measured"] - t[1]["model"]))
        d = 1000 * (q["measured"] - q["model"])
        found.append((abs(d) / 1000 / max(r["r0_m"], 1e-9),
                      f"The measured cloth lies {abs(d):.1f} mm further {'out' if d > 0 else 'in'} than the model's at "
                      f"r0 {100 * r['r0_m']:.1f} cm (outside the model's interval at {len(moved)} of "
                      f"{len(g['rings'])} rings)."))
    return [s for _, s in sorted(found, key=lambda t: -t[0])]
