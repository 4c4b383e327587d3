"""Effects in a fit and in presets, read from the native effect registry (``sim.effects()``).

A fit's effects argument is {name: {param: value or None}}: a value fixes the parameter, None fits it; an
effect given as {name: None} or {name: {}} fits all its parameters from their off values; parameters of a
named effect that are not given stay at their off value (fixed). ``EffectPlan`` turns that into what the fitter
needs: the values the models are built with, the fitted parameters as one vector with their off values,
bounds, prior scales (the prior is N(off, prior_scale^2)) and Adam step sizes (a fraction of the registry's
moderate strength), and the presets' ``active_effects`` block:
    {name: {param: {"value", "unit", "fitted", "std" and "interval90" (fitted, bdp posterior)}}}.
"""
import math

import numpy as np

from . import sim
from ._native import InputError

__all__ = ["EffectPlan", "registry", "validate_active_effects", "active_effect_values", "sample_effect_values"]


def registry():
    """{name: registry entry} in registry order."""
    return {e["name"]: e for e in sim.effects()}


def _entry(reg, name, where):
    if name not in reg:
        raise InputError(f"{where}: unknown effect {name!r} (registered: {', '.join(reg) or 'none'})")
    return reg[name]


def _param(entry, param, where):
    for p in entry["parameters"]:
        if p["name"] == param:
            return p
    names = ", ".join(p["name"] for p in entry["parameters"])
    raise InputError(f"{where}: effect {entry['name']!r} has no parameter {param!r} (parameters: {names})")


class EffectPlan:
    """The active effects of a fit: fixed values and the fitted parameters (see the module doc)."""

    def __init__(self, spec=None):
        reg = registry()
        if spec is None:
            spec = {}
        if not isinstance(spec, dict):
            raise InputError(f"effects: expected {{name: {{parameter: value or None}}}}, got {type(spec).__name__}")
        self.fixed = {}   # name -> {param: value} for every parameter of every active effect (fitted: start)
        self.free = []    # [(name, parameter registry entry)] in registry order
        for name in reg:  # registry order, whatever the argument's order
            if name not in spec:
                continue
            entry = reg[name]
            given = spec[name]
            if given is None:
                given = {}
            if not isinstance(given, dict):
                raise InputError(f"effects: {name}: expected {{parameter: value or None}}, got {type(given).__name__}")
            fit_all = not given
            values = {}
            for p in entry["parameters"]:
                value = given.get(p["name"], p["off"] if not fit_all else None)
                if value is None and p.get("structural"):
                    # A structural parameter (disk_contact's clamp radius) chooses the model's structure and has
                    # no gradient: held at the value given, or at its registry strength when the effect is fitted.
                    value = p["moderate"]
                if value is None:
                    self.free.append((name, p))
                    value = p["off"]
                values[p["name"]] = value
            for param in given:
                _param(entry, param, f"effects: {name}.{param}")
            self.fixed[name] = sim.effect_values({name: values})[name]
        for name in spec:
            _entry(reg, name, "effects")
        self.names = [f"{n}.{p['name']}" for n, p in self.free]
        self.off = np.array([p["off"] for _, p in self.free], dtype=float)
        self.lower = np.array([p["lower"] for _, p in self.free], dtype=float)
        self.upper = np.array([p["upper"] for _, p in self.free], dtype=float)
        self.prior_scale = np.array([p["prior_scale"] for _, p in self.free], dtype=float)
        self.moderate = np.array([abs(p["moderate"] - p["off"]) for _, p in self.free], dtype=float)

    @property
    def size(self):
        return len(self.free)

    def describe(self):
        """{name: {param: value or "fitted"}}: what was asked (recorded in a preset's provenance)."""
        out = {n: dict(v) for n, v in self.fixed.items()}
        for n, p in self.free:
            out[n][p["name"]] = "fitted"
        return out

    def clip(self, vector):
        """vector clipped to the parameters' bounds, and the mask of entries inside them (gradient flows)."""
        v = np.asarray(vector, dtype=float)
        inside = (v >= self.lower) & (v <= self.upper)
        return np.clip(v, self.lower, self.upper), inside

    def values(self, vector=None):
        """{name: {param: value}} for the models: the fixed values with the fitted ones from `vector`."""
        out = {n: dict(v) for n, v in self.fixed.items()}
        if vector is not None:
            for (n, p), value in zip(self.free, np.asarray(vector, dtype=float)):
                out[n][p["name"]] = float(value)
        return out

    def gather(self, blocks):
        """The fitted parameters' entries of a gradient dict (ClothModel.backward) as a vector."""
        return np.array([float(blocks[key]) for key in self.names], dtype=float)

    def start_candidates(self, start):
        """Starting points the fit tries for its fitted effects: `start`; each fitted effect's primary parameter
        at +- its moderate strength (the others at `start`); and, with the primary at + moderate, each other
        fitted parameter of that effect at +- its own moderate strength. At an off value some parameters have no
        gradient (a tilt's azimuth at zero angle), and a direction far from the truth is a slow path."""
        reg = registry()
        base = np.asarray(start, dtype=float).copy()
        out = [base]

        def add(c):
            if np.all((c >= self.lower) & (c <= self.upper)) and not any(np.array_equal(c, o) for o in out):
                out.append(c)

        for i, (n, p) in enumerate(self.free):
            if p["name"] != reg[n]["parameters"][0]["name"]:
                continue
            for sign in (1.0, -1.0):
                c = base.copy()
                c[i] = p["off"] + sign * self.moderate[i]
                add(c)
            for j, (m, q) in enumerate(self.free):
                if m != n or j == i:
                    continue
                for sign in (1.0, -1.0):
                    c = base.copy()
                    c[i] = p["off"] + self.moderate[i]
                    c[j] = q["off"] + sign * self.moderate[j]
                    add(c)
        return out

    def preset_block(self, mean=None, std=None):
        """The presets' active_effects block for fitted means (and bdp posterior sds)."""
        reg = registry()
        out = {}
        for n, values in self.values(mean).items():
            units = {p["name"]: p["unit"] for p in reg[n]["parameters"]}
            out[n] = {param: {"value": float(v), "unit": units[param], "fitted": False} for param, v in values.items()}
        for i, (n, p) in enumerate(self.free):
            e = out[n][p["name"]]
            e["fitted"] = True
            if std is not None:
                s = float(std[i])
                e["std"] = s
                e["interval90"] = [float(max(self.lower[i], e["value"] - 1.645 * s)),
                                   float(min(self.upper[i], e["value"] + 1.645 * s))]
        return out


def validate_active_effects(block, source="preset"):
    """Checks a preset's active_effects block against the registry (names, units, values in range, std >= 0,
    interval90 ordered); InputError naming "active_effects.name.param"."""
    if not isinstance(block, dict):
        raise InputError(f"{source}: active_effects must be an object {{effect: {{parameter: {{value, unit}}}}}}")
    reg = registry()
    for name, params in block.items():
        where = f"{source}: active_effects.{name}"
        entry = _entry(reg, name, where)
        if not isinstance(params, dict):
            raise InputError(f"{where}: expected an object {{parameter: {{value, unit}}}}")
        for param, e in params.items():
            at = f"{where}.{param}"
            spec = _param(entry, param, at)
            if not isinstance(e, dict):
                raise InputError(f"{at}: expected an object {{value, unit, ...}}")
            value = e.get("value")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InputError(f"{at}: value must be a finite number, got {value!r}")
            if not spec["lower"] <= value <= spec["upper"]:
                raise InputError(f"{at}: value {value} outside [{spec['lower']}, {spec['upper']}] {spec['unit']}")
            if e.get("unit") != spec["unit"]:
                raise InputError(f"{at}: unit must be {spec['unit']!r}, got {e.get('unit')!r}")
            if "std" in e:
                s = e["std"]
                if isinstance(s, bool) or not isinstance(s, (int, float)) or not math.isfinite(s) or s < 0:
                    raise InputError(f"{at}: std must be a finite number >= 0, got {s!r}")
            if "interval90" in e:
                iv = e["interval90"]
                if (not isinstance(iv, list) or len(iv) != 2
                        or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) for v in iv)
                        or iv[0] > iv[1]):
                    raise InputError(f"{at}: interval90 must be [low, high] finite numbers, got {iv!r}")
    return block


def active_effect_values(block):
    """{name: {param: value}} of a preset's active_effects block (its means)."""
    return {n: {p: float(e["value"]) for p, e in params.items()} for n, params in (block or {}).items()}


def sample_effect_values(block, rng, count):
    """`count` draws {name: {param: value}} from a preset's active_effects: fitted parameters with a posterior
    sd are drawn from N(value, std^2) clipped to their bounds, the rest stay at their value. None when the
    block is empty (the base model). rng is used only when some parameter has a posterior sd."""
    if not block:
        return None
    reg = registry()
    base = active_effect_values(block)
    draws = [{n: dict(v) for n, v in base.items()} for _ in range(count)]
    for n, params in block.items():
        for p, e in params.items():
            s = float(e.get("std", 0.0) or 0.0)
            if s <= 0:
                continue
            spec = _param(reg[n], p, n)
            z = rng.standard_normal(count)
            for k in range(count):
                draws[k][n][p] = float(np.clip(e["value"] + s * z[k], spec["lower"], spec["upper"]))
    return draws
