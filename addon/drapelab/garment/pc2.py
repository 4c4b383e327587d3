"""PC2 point caches: the vertex animation Blender's Mesh Cache modifier plays (Debian's Blender has no Alembic).

Format (little-endian; Blender's MOD_meshcache_pc2): a 32-byte header
    char[12] "POINTCACHE2\\0", int32 version = 1, int32 num_points, float32 start_frame, float32 sample_rate,
    int32 num_samples
then num_samples frames of num_points float32 (x, y, z). The Mesh Cache modifier needs the mesh's vertex order.

Writing (``PC2Writer``) never leaves a partial frame or a corrupt file at the path:
- the cache is built in a temporary file beside the path (``.tmp_*.pc2``); the path itself is not touched
  until the first frame is complete, so an existing cache stays playable until it is replaced by a valid one;
- each frame's data is written after the frames done, and only then is the header's num_samples raised to
  include it (one 4-byte write): a reader sees the frames counted in the header, all complete, and at most
  some bytes of the frame being written after them (``read_pc2`` ignores such a tail, as Blender does);
- after its first frame the temporary file is renamed into place (os.replace: atomic); later frames are
  appended to the same open file, so playback can start while the bake runs;
- close() (also on an exception or Ctrl-C inside ``with``) keeps every frame done; a writer closed before its
  first frame removes its temporary file and leaves the path as it was.
Power-loss durability is not promised (no fsync per frame; close() syncs once).

``read_pc2`` checks the header and the file size before allocating anything (MAX_READ_BYTES), and names the
problem of a truncated or corrupt file.
"""
import os
import struct
import tempfile

import numpy as np

from . import InputError

__all__ = ["PC2Writer", "read_pc2", "read_pc2_header", "write_pc2", "HEADER", "HEADER_SIZE", "MAX_READ_BYTES"]

MAGIC = b"POINTCACHE2\0"
HEADER = struct.Struct("<12siiffi")
HEADER_SIZE = HEADER.size          # 32
COUNT_OFFSET = 28                  # byte offset of num_samples
MAX_POINTS = 1 << 26               # 67M vertices: more is a corrupt header
MAX_READ_BYTES = 8 << 30           # read_pc2 refuses to load more than this (default)
FLOAT32_MAX = float(np.finfo(np.float32).max)


class PC2Writer:
    """Writes a PC2 cache frame by frame (see the module docstring for the guarantees).

    path: the cache file; num_vertices: vertices per frame; start_frame: the scene frame of the first sample;
    sample_rate: frames between samples (1.0: one sample per frame). ``write_frame(positions (V, 3))``
    appends a frame; ``close()`` finishes. Usable as a context manager. ``frames_written`` counts frames.
    """

    def __init__(self, path, num_vertices, start_frame=1, sample_rate=1.0):
        self.path = os.fspath(path)
        if isinstance(num_vertices, bool) or not isinstance(num_vertices, (int, np.integer)) or \
                not 1 <= num_vertices <= MAX_POINTS:
            raise InputError(f"num_vertices: expected an integer in [1, {MAX_POINTS}], got {num_vertices!r}")
        self.num_vertices = int(num_vertices)
        self.start_frame = _finite(start_frame, "start_frame")
        self.sample_rate = _finite(sample_rate, "sample_rate")
        if self.sample_rate <= 0:
            raise InputError(f"sample_rate: must be > 0, got {sample_rate!r}")
        folder = os.path.dirname(os.path.abspath(self.path))
        if os.path.isdir(self.path):
            raise InputError(f"{self.path}: cannot write a PC2 cache: it is a directory")
        if not os.path.isdir(folder):
            raise InputError(f"{self.path}: cannot write a PC2 cache: folder {folder} does not exist")
        fd, self._tmp = tempfile.mkstemp(prefix=".tmp_", suffix=".pc2", dir=folder)
        self._fd = fd
        self.frames_written = 0
        self._in_place = False
        try:
            os.pwrite(fd, HEADER.pack(MAGIC, 1, self.num_vertices, self.start_frame, self.sample_rate, 0), 0)
        except OSError:
            self._abandon()
            raise

    def write_frame(self, positions):
        """Appends one frame of positions (V, 3) (finite, within float32 range); the header counts it only
        once it is completely written."""
        if self._fd is None:
            raise InputError(f"{self.path}: the PC2 writer is closed")
        x = np.asarray(positions, dtype=np.float64)
        if x.shape != (self.num_vertices, 3):
            raise InputError(f"positions: expected shape ({self.num_vertices}, 3), got {x.shape}")
        bad = ~np.isfinite(x) | (np.abs(x) > FLOAT32_MAX)
        if bad.any():
            v = int(np.argwhere(bad)[0][0])
            raise InputError(f"positions: vertex {v} is not finite in float32 ({x[v].tolist()}); frame "
                             f"{self.frames_written} not written")
        data = np.ascontiguousarray(x, dtype="<f4").tobytes()
        offset = HEADER_SIZE + self.frames_written * len(data)
        _pwrite_all(self._fd, data, offset)
        _pwrite_all(self._fd, struct.pack("<i", self.frames_written + 1), COUNT_OFFSET)
        self.frames_written += 1
        if not self._in_place:
            os.replace(self._tmp, self.path)  # the first complete frame: the cache appears at its path
            self._in_place = True
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(self.path, 0o666 & ~umask)

    def close(self):
        """Finishes the cache (keeping every frame written); without a frame, removes the temporary file."""
        if self._fd is None:
            return
        if not self._in_place:
            self._abandon()
            return
        try:
            os.fsync(self._fd)
        finally:
            os.close(self._fd)
            self._fd = None

    def _abandon(self):
        try:
            os.close(self._fd)
        except OSError:
            pass
        self._fd = None
        try:
            os.unlink(self._tmp)
        except OSError:
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __del__(self):
        if getattr(self, "_fd", None) is not None:
            self.close()


def _pwrite_all(fd, data, offset):
    view = memoryview(data)
    while view:
        n = os.pwrite(fd, view, offset)
        view, offset = view[n:], offset + n


def _finite(value, name):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a number, got {value!r}") from None
    if not np.isfinite(v) or abs(v) > FLOAT32_MAX:
        raise InputError(f"{name}: must be a finite float32 number, got {value!r}")
    return v


def write_pc2(path, frames, start_frame=1, sample_rate=1.0):
    """Writes (frames, V, 3) positions as a PC2 cache (PC2Writer, frame by frame)."""
    x = np.asarray(frames, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3 or x.shape[0] < 1:
        raise InputError(f"frames: expected shape (frames >= 1, V, 3), got {x.shape}")
    with PC2Writer(path, x.shape[1], start_frame, sample_rate) as w:
        for frame in x:
            w.write_frame(frame)


def read_pc2_header(path):
    """{num_points, start_frame, sample_rate, num_samples, file_size} of a PC2 file, checked against its size."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            head = f.read(HEADER_SIZE)
            # the size after the header: a writer raises the count only after the frame's data, so a cache
            # growing while it is read has at least the frames its header counted when read
            size = os.fstat(f.fileno()).st_size
    except OSError as e:
        raise InputError(f"{path}: cannot read PC2 cache: {e.strerror or e}") from None
    if len(head) < HEADER_SIZE:
        raise InputError(f"{path}: not a PC2 cache: {len(head)} bytes, shorter than the {HEADER_SIZE}-byte header")
    magic, version, points, start, rate, samples = HEADER.unpack(head)
    if magic != MAGIC:
        raise InputError(f"{path}: not a PC2 cache: header starts with {magic!r}, expected {MAGIC!r}")
    if version != 1:
        raise InputError(f"{path}: PC2 version {version} is not supported (expected 1)")
    if not 1 <= points <= MAX_POINTS:
        raise InputError(f"{path}: corrupt PC2 header: num_points {points} outside [1, {MAX_POINTS}]")
    if samples < 0:
        raise InputError(f"{path}: corrupt PC2 header: num_samples {samples} is negative")
    if not np.isfinite(start) or not np.isfinite(rate) or rate <= 0:
        raise InputError(f"{path}: corrupt PC2 header: start_frame {start} and sample_rate {rate} must be finite, "
                         "the rate > 0")
    need = HEADER_SIZE + samples * points * 12
    if size < need:
        complete = (size - HEADER_SIZE) // (points * 12)
        raise InputError(f"{path}: truncated PC2 cache: the header counts {samples} frames of {points} vertices "
                         f"({need} bytes) but the file has {size} bytes ({complete} complete frames)")
    return {"num_points": int(points), "start_frame": float(start), "sample_rate": float(rate),
            "num_samples": int(samples), "file_size": int(size)}


def read_pc2(path, max_bytes=MAX_READ_BYTES):
    """(frames, V, 3) float64 positions of a PC2 cache. Frames beyond the header's count (a frame being
    written) are ignored. Errors (InputError) name a short, corrupt or truncated file, a cache larger than
    max_bytes (checked before reading it), and non-finite positions (frame and vertex)."""
    h = read_pc2_header(path)
    nbytes = h["num_samples"] * h["num_points"] * 12
    if nbytes > max_bytes:
        raise InputError(f"{os.fspath(path)}: PC2 cache of {nbytes} bytes is above the {max_bytes}-byte limit")
    with open(path, "rb") as f:
        f.seek(HEADER_SIZE)
        data = f.read(nbytes)
    if len(data) != nbytes:  # the file shrank since the header was read
        raise InputError(f"{os.fspath(path)}: truncated PC2 cache while reading")
    x = np.frombuffer(data, dtype="<f4").reshape(h["num_samples"], h["num_points"], 3).astype(np.float64)
    bad = ~np.isfinite(x)
    if bad.any():
        frame, vertex, _ = (int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"{os.fspath(path)}: corrupt PC2 cache: non-finite position at frame {frame}, vertex {vertex}")
    return x
