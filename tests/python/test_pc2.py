"""Tests of drapelab.garment.pc2: the PC2 point cache Blender's Mesh Cache modifier plays. Format, frame-by-frame
writing that never shows a partial frame or a corrupt file, and a reader that names every kind of bad file
(property-based fuzzing with Debian's python3-hypothesis, as tests/python/test_fuzz_loaders.py)."""
import os
import struct

import numpy as np
import pytest

from drapelab.garment import InputError, pc2

hypothesis = pytest.importorskip("hypothesis", reason="python3-hypothesis is not installed (./drapelab installs it)")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

FUZZ = settings(max_examples=300, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def frames(k=4, v=7, seed=0):
    return np.random.default_rng(seed).normal(size=(k, v, 3))


def test_header_and_round_trip(tmp_path):
    x = frames()
    path = tmp_path / "a.pc2"
    pc2.write_pc2(path, x, start_frame=10, sample_rate=0.5)
    raw = path.read_bytes()
    assert len(raw) == 32 + 4 * 7 * 12
    assert raw[:12] == b"POINTCACHE2\0"
    assert struct.unpack("<iiffi", raw[12:32]) == (1, 7, 10.0, 0.5, 4)
    assert np.array_equal(np.frombuffer(raw[32:44], "<f4"), x[0, 0].astype(np.float32))   # frame 0, vertex 0
    y = pc2.read_pc2(path)
    assert y.shape == (4, 7, 3) and y.dtype == np.float64
    assert np.array_equal(y, x.astype(np.float32).astype(np.float64))
    assert pc2.read_pc2_header(path) == {"num_points": 7, "start_frame": 10.0, "sample_rate": 0.5, "num_samples": 4,
                                         "file_size": len(raw)}
    assert sorted(os.listdir(tmp_path)) == ["a.pc2"]


def test_the_path_appears_at_the_first_complete_frame_and_grows(tmp_path):
    path = tmp_path / "cache.pc2"
    x = frames(3)
    with pc2.PC2Writer(path, 7) as w:
        assert not path.exists()                                   # nothing at the path before a frame
        for k in range(3):
            w.write_frame(x[k])
            assert pc2.read_pc2(path).shape == (k + 1, 7, 3)        # readable while the bake runs
            assert w.frames_written == k + 1
    assert np.allclose(pc2.read_pc2(path), x, atol=1e-6)


def test_an_existing_cache_stays_until_replaced(tmp_path):
    path = tmp_path / "cache.pc2"
    pc2.write_pc2(path, frames(5, seed=1))
    old = path.read_bytes()
    w = pc2.PC2Writer(path, 7)
    assert path.read_bytes() == old                                # still the old, valid cache
    w.close()                                                      # closed before any frame
    assert path.read_bytes() == old and sorted(os.listdir(tmp_path)) == ["cache.pc2"]
    with pc2.PC2Writer(path, 7) as w:
        w.write_frame(frames(1, seed=2)[0])
    assert pc2.read_pc2(path).shape == (1, 7, 3)


def test_frames_done_survive_an_interruption(tmp_path):
    path = tmp_path / "cache.pc2"
    x = frames(6)
    with pytest.raises(KeyboardInterrupt):
        with pc2.PC2Writer(path, 7) as w:
            for k in range(6):
                if k == 4:
                    raise KeyboardInterrupt  # Ctrl-C mid-bake
                w.write_frame(x[k])
    assert np.allclose(pc2.read_pc2(path), x[:4], atol=1e-6)
    assert sorted(os.listdir(tmp_path)) == ["cache.pc2"]


def test_a_partial_frame_after_the_counted_ones_is_never_read(tmp_path):
    """What a reader sees mid-write: the data of frame k written, the header still counting k frames."""
    path = tmp_path / "cache.pc2"
    x = frames(3)
    pc2.write_pc2(path, x[:2])
    with open(path, "ab") as f:
        f.write(x[2].astype("<f4").tobytes()[:50])                 # part of the next frame
    assert np.allclose(pc2.read_pc2(path), x[:2], atol=1e-6)


def test_a_frame_written_while_the_header_is_read_is_never_miscounted(tmp_path, monkeypatch):
    """The race a mid-bake reader meets: the writer completes a frame (data, then count) while the reader opens
    the file. The size is taken after the header, so it holds every frame the header counts."""
    path = tmp_path / "cache.pc2"
    x = frames(3)
    with pc2.PC2Writer(path, 7) as w:
        w.write_frame(x[0])
        w.write_frame(x[1])
        real_open = open

        def open_while_a_frame_lands(*args, **kwargs):
            if w.frames_written < 3:
                w.write_frame(x[2])
            return real_open(*args, **kwargs)
        monkeypatch.setattr(pc2, "open", open_while_a_frame_lands, raising=False)
        h = pc2.read_pc2_header(path)
        assert h["num_samples"] == 3 and h["file_size"] == pc2.HEADER_SIZE + 3 * 7 * 12


def test_writer_refuses_bad_frames_without_writing_them(tmp_path):
    path = tmp_path / "cache.pc2"
    with pc2.PC2Writer(path, 7) as w:
        w.write_frame(frames(1)[0])
        with pytest.raises(InputError, match=r"expected shape \(7, 3\)"):
            w.write_frame(np.zeros((6, 3)))
        bad = frames(1)[0]
        bad[3, 1] = np.nan
        with pytest.raises(InputError, match="vertex 3 is not finite.*frame 1 not written"):
            w.write_frame(bad)
        huge = np.full((7, 3), 1e39)
        with pytest.raises(InputError, match="vertex 0 is not finite in float32"):
            w.write_frame(huge)
    assert pc2.read_pc2(path).shape == (1, 7, 3)
    with pytest.raises(InputError, match="closed"):
        w.write_frame(frames(1)[0])
    with pytest.raises(InputError, match="num_vertices"):
        pc2.PC2Writer(tmp_path / "b.pc2", 0)
    with pytest.raises(InputError, match="sample_rate"):
        pc2.PC2Writer(tmp_path / "b.pc2", 3, sample_rate=0)
    with pytest.raises(InputError, match="does not exist"):
        pc2.PC2Writer(tmp_path / "missing" / "b.pc2", 3)
    with pytest.raises(InputError, match="directory"):
        pc2.PC2Writer(tmp_path, 3)
    assert sorted(os.listdir(tmp_path)) == ["cache.pc2"]


def header(points=7, samples=2, version=1, magic=b"POINTCACHE2\0", start=1.0, rate=1.0):
    return struct.pack("<12siiffi", magic, version, points, start, rate, samples)


@pytest.mark.parametrize("data, message", [
    (b"", "shorter than the 32-byte header"),
    (b"POINTCACHE2\0" + b"\0" * 10, "shorter than the 32-byte header"),
    (header(magic=b"POINTCACHE3\0"), "not a PC2 cache: header starts with"),
    (header(version=2), "PC2 version 2 is not supported"),
    (header(points=0), "num_points 0 outside"),
    (header(points=-5), "num_points -5 outside"),
    (header(points=1 << 30), "num_points 1073741824 outside"),
    (header(samples=-1), "num_samples -1 is negative"),
    (header(rate=0.0), "sample_rate 0.0"),
    (header(start=float("nan")), "must be finite"),
    (header(samples=2) + b"\0" * (7 * 12 + 5), "truncated PC2 cache: the header counts 2 frames of 7 vertices"),
    (header(points=1000000, samples=1000000), "truncated"),                   # checked before allocating
    (header(points=1, samples=1) + struct.pack("<3f", 0, float("inf"), 0), "non-finite position at frame 0, vertex 0"),
])
def test_reader_names_bad_files(tmp_path, data, message):
    path = tmp_path / "bad.pc2"
    path.write_bytes(data)
    with pytest.raises(InputError, match=message):
        pc2.read_pc2(path)


def test_reader_size_cap_and_missing_file(tmp_path):
    path = tmp_path / "a.pc2"
    pc2.write_pc2(path, frames())
    with pytest.raises(InputError, match="above the 100-byte limit"):
        pc2.read_pc2(path, max_bytes=100)
    with pytest.raises(InputError, match="cannot read PC2 cache"):
        pc2.read_pc2(tmp_path / "missing.pc2")
    empty = tmp_path / "empty.pc2"
    empty.write_bytes(header(samples=0))
    assert pc2.read_pc2(empty).shape == (0, 7, 3)


def valid_file():
    return header(points=3, samples=2) + np.arange(18, dtype="<f4").tobytes()


@FUZZ
@given(st.binary(max_size=200))
def test_fuzz_random_bytes(tmp_path, data):
    check_reader(tmp_path, data)


@FUZZ
@given(st.integers(0, 49), st.binary(min_size=1, max_size=8), st.sampled_from(["replace", "truncate", "append"]))
def test_fuzz_mutated_valid_file(tmp_path, offset, chunk, operation):
    data = bytearray(valid_file())
    if operation == "replace":
        data[offset:offset + len(chunk)] = chunk
    elif operation == "truncate":
        data = data[:offset]
    else:
        data += chunk
    check_reader(tmp_path, bytes(data))


def check_reader(tmp_path, data):
    path = tmp_path / "fuzz.pc2"
    path.write_bytes(data)
    try:
        x = pc2.read_pc2(path)
    except InputError:
        return
    h = pc2.read_pc2_header(path)
    assert x.shape == (h["num_samples"], h["num_points"], 3) and np.isfinite(x).all()
    assert len(data) >= 32 + x.size * 4
