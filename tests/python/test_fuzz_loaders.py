"""Property-based fuzzing of the loaders of user files written in Python (issue 16): a material preset
(infer.load_preset / infer.validate_preset) and a dataset manifest (measure.load_manifest, the native CSV reader
behind the facade). Whatever the input, a loader returns or raises InputError (a ValueError) naming the
problem: never another exception. The native loaders are fuzzed with libFuzzer (tests/fuzz, ./drapelab fuzz).

Uses Debian's python3-hypothesis (installed by ./drapelab); without it the tests skip and say so.
"""
import copy
import json
import os

import pytest

from drapelab import infer, measure
from drapelab.measure import InputError

hypothesis = pytest.importorskip("hypothesis", reason="python3-hypothesis is not installed (./drapelab installs it)")
from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PRESET = os.path.join(ROOT, "assets", "presets", "fabric_02_cotton_blue_bdp.json")
MANIFEST = os.path.join(ROOT, "assets", "cusick", "manifest.csv")

# No example database: it would be written into the working directory (the repository).
FUZZ = settings(max_examples=300, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

# JSON values of every kind, including the awkward ones: huge integers, NaN and infinities (Python's json
# reads and writes them), empty containers, deep nesting.
JSON_SCALARS = (st.none() | st.booleans() | st.integers() | st.integers(min_value=10 ** 300, max_value=10 ** 400)
                | st.floats() | st.text(max_size=20))
JSON_VALUES = st.recursive(JSON_SCALARS, lambda inner: st.lists(inner, max_size=6)
                           | st.dictionaries(st.text(max_size=12), inner, max_size=6), max_leaves=30)


def valid_preset():
    with open(PRESET) as f:
        return json.load(f)


def paths(value, prefix=()):
    """Every key path into nested dicts and lists (the root is ())."""
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from paths(v, prefix + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from paths(v, prefix + (i,))


def mutate(preset, path, operation, value):
    """Replaces, deletes, or adds beside, the value at `path` (the root can only be replaced)."""
    if not path:
        return value
    parent = preset
    for key in path[:-1]:
        parent = parent[key]
    key = path[-1]
    if operation == "replace":
        parent[key] = value
    elif operation == "delete":
        del parent[key]
    elif isinstance(parent, list):
        parent.insert(key, value)
    else:
        parent[f"{key}_extra"] = value
    return preset


def load_or_input_error(load, *args):
    """The loader's result, or None when it raised InputError; any other exception fails the test."""
    try:
        return load(*args)
    except InputError as e:
        assert str(e), "an InputError must say what is wrong"
        return None


def write(tmp_path, name, data):
    path = tmp_path / name
    path.write_bytes(data)
    return str(path)


# ---------------------------------------------------------------- presets
def test_the_shipped_preset_loads():
    assert infer.load_preset(PRESET)["kind"] == "drapelab-material-preset"


@FUZZ
@given(data=st.binary(max_size=2000))
@example(data=b"[" * 5000)  # nesting deeper than the recursion limit
@example(data=b'{"kind": "drapelab-material-preset", "schema_version": 1e999}')
@example(data=b"\xff\xfe{}")  # not UTF-8
def test_preset_from_arbitrary_bytes(tmp_path, data):
    load_or_input_error(infer.load_preset, write(tmp_path, "preset.json", data))


@FUZZ
@given(value=JSON_VALUES)
def test_preset_from_arbitrary_json(tmp_path, value):
    text = json.dumps(value).encode()
    load_or_input_error(infer.load_preset, write(tmp_path, "preset.json", text))


@FUZZ
@given(data=st.data())
def test_preset_with_mutations_loads_or_says_why(tmp_path, data):
    preset = valid_preset()
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        path = data.draw(st.sampled_from(sorted(paths(preset), key=repr)), label="path")
        operation = data.draw(st.sampled_from(["replace", "delete", "add"]), label="operation")
        preset = mutate(preset, path, operation, data.draw(JSON_VALUES, label="value"))
    checked = load_or_input_error(infer.validate_preset, copy.deepcopy(preset), "mutated")
    on_disk = load_or_input_error(infer.load_preset, write(tmp_path, "preset.json", json.dumps(preset).encode()))
    assert (checked is None) == (on_disk is None)  # the file loads exactly when the value validates


@pytest.mark.parametrize("value", ["0", True, [0.1], None])
def test_a_preset_table_entry_that_is_not_a_number_is_named(value):
    """The fuzzer's find (CI, 2026-11-28): a string "0" in log_std was coerced by one check and compared raw by
    the next (a TypeError); any non-number in a table is now an InputError naming the table."""
    preset = valid_preset()
    preset["posterior"]["bend"]["log_std"][0][0] = value
    with pytest.raises(InputError, match="posterior bend log_std"):
        infer.validate_preset(preset, "mutated")


# ---------------------------------------------------------------- manifests
# CSV-like text: characters and whole tokens (column names, numbers' spellings, a BOM, NUL, a 300-character
# path component, longer than a file name may be).
MANIFEST_TEXT = st.lists(st.sampled_from(list('abcdefghijklmnopqrstuvwxyz_0123456789.,/"\r\n -+e') +
                                         ["fabric", "sample", "capture", "silhouette", "mesh", "name", "density_kg_m2",
                                          "thickness_mm", "nan", "inf", "1e999", "\ufeff", "\0", "a" * 300]),
                         max_size=120).map("".join)


def test_the_bundled_manifest_loads():
    assert len(measure.load_manifest(MANIFEST, check_files=True)) == 3


@FUZZ
@given(data=st.binary(max_size=2000), check_files=st.booleans())
def test_manifest_from_arbitrary_bytes(tmp_path, data, check_files):
    load_or_input_error(measure.load_manifest, write(tmp_path, "manifest.csv", data), check_files)


@FUZZ
@given(text=MANIFEST_TEXT, check_files=st.booleans())
@example(text="fabric,sample,capture,silhouette\n1,1,1," + "a" * 300 + ".png\n", check_files=True)
def test_manifest_from_csv_like_text(tmp_path, text, check_files):
    path = write(tmp_path, "manifest.csv", text.encode("utf-8", "surrogatepass"))
    load_or_input_error(measure.load_manifest, path, check_files)


@FUZZ
@given(data=st.data(), check_files=st.booleans())
def test_manifest_with_mutated_lines(tmp_path, data, check_files):
    with open(MANIFEST) as f:
        lines = f.read().splitlines()
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        i = data.draw(st.integers(0, len(lines) - 1), label="line")
        fields = lines[i].split(",")
        j = data.draw(st.integers(0, len(fields) - 1), label="field")
        fields[j] = data.draw(MANIFEST_TEXT, label="value")
        lines[i] = ",".join(fields)
    path = write(tmp_path, "manifest.csv", "\n".join(lines).encode("utf-8", "surrogatepass"))
    rows = load_or_input_error(measure.load_manifest, path, check_files)
    if rows is not None:
        assert all(isinstance(r["fabric"], int) and r["silhouette"] for r in rows)
