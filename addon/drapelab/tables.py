"""Published material tables: the starting tables of the released training scripts of Gong, Mao, Wang,
"Bayesian Differentiable Physics for Cloth Digitalization", CVPR 2024 (see README.md, "Data formats").

Stretch table (6, 4), N/m: rows are the six samples of the largest principal stretch and its direction
(row 0 the small-strain sample shared by all directions, rows 1..5 five directions from the weft to the warp
at the larger strain), columns (c11, c12, c22, c33) = weft stiffness, Poisson coupling, warp stiffness, shear.
Bend table (3, 5), N m: rows are the bias angle of an edge to the weft (0, 45, 90 degrees), columns five
samples of the curvature measure. Density in kg/m^2.

The arrays are read-only; copy them (``np.array(t)``) to edit.
"""
from dataclasses import dataclass

import numpy as np

__all__ = ["MaterialPreset", "STRETCH_COLUMNS", "COTTON_BLUE", "WOOL_RED", "COTTON_PINK", "PRESETS", "preset",
           "stretch_table", "bend_table"]

STRETCH_COLUMNS = ("c11", "c12", "c22", "c33")
STRETCH_SHAPE = (6, 4)
BEND_SHAPE = (3, 5)


def _frozen(a):
    a = np.array(a, dtype=np.float64)
    a.flags.writeable = False
    return a


def stretch_table(c11, c12, c22, c33):
    """A (6, 4) stretch table from the four per-coefficient lists of six samples each (as published)."""
    cols = [np.asarray(c, dtype=np.float64) for c in (c11, c12, c22, c33)]
    for name, c in zip(STRETCH_COLUMNS, cols):
        if c.shape != (6,):
            raise ValueError(f"stretch_table: {name} must have 6 samples, got shape {c.shape}")
    return np.column_stack(cols)


def bend_table(rows):
    """A (3, 5) bend table from three rows (bias 0, 45, 90 degrees) of five curvature samples."""
    t = np.asarray(rows, dtype=np.float64)
    if t.shape != BEND_SHAPE:
        raise ValueError(f"bend_table: expected shape {BEND_SHAPE}, got {t.shape}")
    return t


@dataclass(frozen=True)
class MaterialPreset:
    name: str
    density: float       # kg/m^2
    stretch: np.ndarray  # (6, 4) N/m
    bend: np.ndarray     # (3, 5) N m
    source: str

    def as_dict(self):
        return {"name": self.name, "density": self.density, "stretch": self.stretch.tolist(),
                "bend": self.bend.tolist(), "source": self.source}


_SOURCE = "starting tables of the released training scripts of Gong, Mao, Wang (CVPR 2024)"

COTTON_BLUE = MaterialPreset(
    name="Cotton Blue",
    density=0.192,
    stretch=_frozen(stretch_table(
        c11=[150.0862, 189.2275, 51.2988, 36.7329, 58.9375, 207.3079],
        c12=[0.3456, 2.3716, 4.9362, 6.3891, 5.1495, 2.2163],
        c22=[150.4856, 200.7334, 60.3071, 32.7261, 49.8735, 193.4768],
        c33=[10.189, 20.905, 25.393, 30.462, 25.055, 20.669])),
    bend=_frozen(bend_table([
        [1.071e-5, 2.914e-5, 9.287e-5, 9.498e-5, 8.145e-5],
        [2.753e-5, 4.838e-5, 3.838e-5, 7.398e-5, 6.982e-5],
        [2.460e-5, 1.028e-4, 1.234e-4, 1.002e-4, 1.022e-4]])),
    source=_SOURCE)

WOOL_RED = MaterialPreset(
    name="Wool Red",
    density=0.274,
    stretch=_frozen(stretch_table(
        c11=[200.0, 200.0, 100.0, 50.0, 100.0, 200.0],
        c12=[0.1, 1.0, 1.0, 1.0, 1.0, 1.0],
        c22=[200.0, 200.0, 100.0, 50.0, 100.0, 200.0],
        c33=[10.0, 5.0, 10.0, 50.0, 40.0, 30.0])),
    bend=_frozen(bend_table([[7e-5, 9e-5, 1.5e-4, 1.5e-4, 1.5e-4]] * 3)),
    source=_SOURCE)

COTTON_PINK = MaterialPreset(
    name="Cotton Pink",
    density=0.114,
    stretch=_frozen(stretch_table(
        c11=[200.0] * 6,
        c12=[0.1, 1.0, 1.0, 1.0, 1.0, 1.0],
        c22=[200.0] * 6,
        c33=[5.0] * 6)),
    bend=_frozen(bend_table([
        [1.17933348e-05, 2.01009217e-05, 4.01091488e-05, 5.00398193e-05, 5.00369146e-05],
        [1.34345211e-05, 2.01427701e-05, 3.02246364e-05, 4.00903988e-05, 4.00540734e-05],
        [1.15802900e-05, 2.00785103e-05, 4.01148611e-05, 5.00430378e-05, 5.00222191e-05]])),
    source=_SOURCE)

PRESETS = {"cotton_blue": COTTON_BLUE, "wool_red": WOOL_RED, "cotton_pink": COTTON_PINK}


def preset(name):
    """A preset by key ("cotton_blue", "wool_red", "cotton_pink") or display name ("Cotton Blue")."""
    key = str(name).strip().lower().replace(" ", "_").replace("-", "_")
    if key not in PRESETS:
        raise ValueError(f"preset: unknown material {name!r}; known: {', '.join(PRESETS)}")
    return PRESETS[key]
