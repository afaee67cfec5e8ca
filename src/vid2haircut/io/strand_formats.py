"""Strand file formats: ``.npz`` (project), USC ``.data``, Cem Yuksel ``.hair`` and PLY.

All writers are atomic; the format is chosen from the suffix. Readers return a
:class:`~vid2haircut.strands.StrandSet`: strands of different lengths in a file are resampled by
arc length to a common count (the largest in the file, or ``n_points``); strands with fewer than
two points (USC files use one-point strands as placeholders) are dropped. Truncated or malformed
files raise ``ValueError`` naming the file and the byte offset where reading failed.

Layouts (little-endian):

- ``.npz``: ``points`` (N,P,3) float32, optional ``head_model`` 0-d str, and any per-strand
  attribute array with leading dimension N under its own key.
- ``.data`` (USC-HairSalon): int32 strand count, then per strand int32 n and n*3 float32.
- ``.hair`` (Cem Yuksel): 128-byte header ``"HAIR"``, uint32 strand count, uint32 point count,
  uint32 flags (bit 0 segments, 1 points, 2 thickness, 3 transparency, 4 color), uint32 default
  segments, float default thickness, float default transparency, 3 float default colour,
  88-byte info string; then the flagged arrays in that order: uint16 segments per strand
  (points - 1), float32 points (x3), thickness, transparency (per point), colour (x3 per point).
  Per-strand attributes ``width``, ``transparency`` and ``color`` map to the per-point arrays
  (written constant along each strand; read back from each strand's root point). The head model
  name travels in the info string as ``head_model=<name>``.
- ``.ply``: see :mod:`vid2haircut.io.strand_ply`.
"""

from __future__ import annotations

import os
import struct
import zipfile
from pathlib import Path

import numpy as np

from vid2haircut.io.atomic import write_bytes, write_npz
from vid2haircut.strands import StrandSet

__all__ = ["load_strands", "save_strands", "STRAND_SUFFIXES"]

STRAND_SUFFIXES = (".npz", ".data", ".hair", ".ply")

_HAIR_HEADER = struct.Struct("<4sIIIIff3f88s")
assert _HAIR_HEADER.size == 128
_HAIR_SEGMENTS, _HAIR_POINTS, _HAIR_THICKNESS, _HAIR_TRANSPARENCY, _HAIR_COLOR = 1, 2, 4, 8, 16
_NPZ_RESERVED = ("points", "head_model")


def load_strands(path: str | os.PathLike, n_points: int | None = None) -> StrandSet:
    """Read a strand file (format from the suffix).

    Args:
        path: ``.npz``, ``.data``, ``.hair`` or ``.ply`` file.
        n_points: resample every strand to this many points; default: keep the file's common
            count (the largest strand's count when lengths differ).

    Returns:
        StrandSet with points (N,P,3) float32.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: strand file not found")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        s = _read_npz(path)
        return s if n_points is None else s.resample(n_points)
    if suffix == ".data":
        polylines, attrs, head = _read_data(path), {}, None
    elif suffix == ".hair":
        polylines, attrs, head = _read_hair(path)
    elif suffix == ".ply":
        from vid2haircut.io.strand_ply import read_ply_polylines

        polylines, attrs, head = read_ply_polylines(path)
    else:
        raise ValueError(f"{path}: unknown strand file suffix {path.suffix!r}; expected one of {STRAND_SUFFIXES}")
    keep = [i for i, pl in enumerate(polylines) if len(pl) >= 2]
    if len(keep) < len(polylines):
        polylines = [polylines[i] for i in keep]
        attrs = {k: v[keep] for k, v in attrs.items()}
    try:
        return StrandSet.from_polylines(polylines, n_points, attrs, head)
    except ValueError as e:  # NaN points, attributes of the wrong shape ...
        raise ValueError(f"{path}: {e}") from None


def save_strands(path: str | os.PathLike, strands: StrandSet) -> Path:
    """Atomically write ``strands`` in the format given by the suffix of ``path``; returns the path."""
    path = Path(path)
    if not isinstance(strands, StrandSet):
        raise TypeError(f"{path}: save_strands needs a StrandSet (vid2haircut.strands), got {type(strands).__name__}; "
                        "wrap (N, P, 3) points as StrandSet(points)")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        _write_npz(path, strands)
    elif suffix == ".data":
        write_bytes(path, _data_bytes(strands))
    elif suffix == ".hair":
        write_bytes(path, _hair_bytes(strands))
    elif suffix == ".ply":
        from vid2haircut.io.strand_ply import ply_bytes

        write_bytes(path, ply_bytes(strands))
    else:
        raise ValueError(f"{path}: unknown strand file suffix {path.suffix!r}; expected one of {STRAND_SUFFIXES}")
    return path


class _Buffer:
    """Sequential little-endian reader over a file's bytes that reports truncation by offset."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def take(self, nbytes: int, what: str) -> memoryview:
        if nbytes < 0 or self.pos + nbytes > len(self.data):
            raise ValueError(f"{self.path}: truncated at byte offset {self.pos}: expected {nbytes} bytes "
                             f"for {what}, file has {len(self.data) - self.pos} left (size {len(self.data)})")
        view = memoryview(self.data)[self.pos:self.pos + nbytes]
        self.pos += nbytes
        return view

    def array(self, dtype: str, count: int, what: str) -> np.ndarray:
        dt = np.dtype(dtype)
        return np.frombuffer(self.take(dt.itemsize * count, what), dt, count)

    def expect_end(self) -> None:
        if self.pos != len(self.data):
            raise ValueError(f"{self.path}: malformed: {len(self.data) - self.pos} unexpected trailing bytes "
                             f"at byte offset {self.pos}")


# -- npz ------------------------------------------------------------------------------------------
def _read_npz(path: Path) -> StrandSet:
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as e:
        raise ValueError(f"{path}: malformed or truncated .npz (size {path.stat().st_size} bytes, "
                         f"failed at byte offset 0 of the archive): {e}") from e
    if "points" not in arrays:
        raise ValueError(f"{path}: no 'points' array (keys: {sorted(arrays)})")
    pts = arrays.pop("points")
    if pts.ndim != 3 or pts.shape[2] != 3 or pts.shape[1] < 2:
        raise ValueError(f"{path}: 'points' must be (N,P,3) with P >= 2, got shape {pts.shape}")
    head = arrays.pop("head_model", None)
    head = None if head is None else str(head[()])
    attrs = {k: v for k, v in arrays.items() if v.ndim >= 1 and v.shape[0] == pts.shape[0]}
    try:
        return StrandSet(pts, attrs, head)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from e


def _write_npz(path: Path, s: StrandSet) -> None:
    bad = [k for k in s.attributes if k in _NPZ_RESERVED]
    if bad:
        raise ValueError(f"{path}: attribute names {bad} clash with reserved .npz keys {_NPZ_RESERVED}")
    extra = {} if s.head_model is None else {"head_model": np.array(s.head_model)}
    write_npz(path, points=s.points, **extra, **s.attributes)


# -- USC .data ------------------------------------------------------------------------------------
def _read_data(path: Path) -> list[np.ndarray]:
    buf = _Buffer(path)
    n = int(buf.array("<i4", 1, "the strand count")[0])
    if n < 0:
        raise ValueError(f"{path}: malformed: negative strand count {n} at byte offset 0")
    polylines = []
    for i in range(n):
        start = buf.pos
        m = int(buf.array("<i4", 1, f"the point count of strand {i}")[0])
        if m < 0:
            raise ValueError(f"{path}: malformed: negative point count {m} for strand {i} at byte offset {start}")
        polylines.append(buf.array("<f4", 3 * m, f"the {m} points of strand {i}").reshape(m, 3))
    buf.expect_end()
    return polylines


def _data_bytes(s: StrandSet) -> bytes:
    n, p = s.points.shape[:2]
    rec = np.empty((n, 4 + 12 * p), np.uint8)
    rec[:, :4] = np.frombuffer(np.int32(p).astype("<i4").tobytes(), np.uint8)
    rec[:, 4:] = s.points.astype("<f4").reshape(n, -1).view(np.uint8)
    return np.int32(n).astype("<i4").tobytes() + rec.tobytes()


# -- Cem Yuksel .hair -----------------------------------------------------------------------------
def _read_hair(path: Path) -> tuple[list[np.ndarray], dict[str, np.ndarray], str | None]:
    buf = _Buffer(path)
    (sig, n, total, flags, d_seg, d_thick, d_transp, c0, c1, c2, info) = _HAIR_HEADER.unpack(
        buf.take(128, "the 128-byte header"))
    if sig != b"HAIR":
        raise ValueError(f"{path}: malformed: signature {sig!r} at byte offset 0 is not b'HAIR'")
    if not flags & _HAIR_POINTS:
        raise ValueError(f"{path}: malformed: header flags {flags:#x} (byte offset 12) say the file has no points array")
    room = len(buf.data) - buf.pos
    if 12 * total > room or (not flags & _HAIR_SEGMENTS and n > total):
        raise ValueError(f"{path}: malformed: the header says {n} strands of {total} points (byte offsets 4, 8), "
                         f"more than the file's {room} bytes after it can hold")
    if flags & _HAIR_SEGMENTS:
        seg = buf.array("<u2", n, f"the segments array ({n} strands)").astype(np.int64)
    else:
        seg = np.full(n, d_seg, np.int64)
    counts = seg + 1
    if int(counts.sum()) != total:
        raise ValueError(f"{path}: malformed: segments imply {int(counts.sum())} points but the header "
                         f"(byte offset 8) says {total}")
    pts = buf.array("<f4", 3 * total, f"the points array ({total} points)").reshape(total, 3)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    attrs: dict[str, np.ndarray] = {}
    for bit, key, width in ((_HAIR_THICKNESS, "width", 1), (_HAIR_TRANSPARENCY, "transparency", 1),
                            (_HAIR_COLOR, "color", 3)):
        if flags & bit:
            arr = buf.array("<f4", width * total, f"the {key} array").reshape(total, width)
            root = arr[np.minimum(starts, max(total - 1, 0))] if total else arr[:0]
            attrs[key] = (root[:, 0] if width == 1 else root).astype(np.float32)
    buf.expect_end()
    polylines = [pts[a:a + c] for a, c in zip(starts, counts)]
    text = info.split(b"\0", 1)[0].decode("utf-8", "replace")
    head = None
    for token in text.replace(";", " ").split():
        if token.startswith("head_model="):
            head = token.split("=", 1)[1] or None
    return polylines, attrs, head


def _hair_bytes(s: StrandSet) -> bytes:
    n, p = s.points.shape[:2]
    if p - 1 > 0xFFFF:
        raise ValueError(f".hair stores segments as uint16: {p} points per strand is too many")
    flags = _HAIR_SEGMENTS | _HAIR_POINTS
    per_point = []
    for bit, key, width in ((_HAIR_THICKNESS, "width", 1), (_HAIR_TRANSPARENCY, "transparency", 1),
                            (_HAIR_COLOR, "color", 3)):
        if key in s.attributes:
            a = np.asarray(s.attributes[key], np.float32).reshape(n, -1)
            if a.shape[1] != width:
                raise ValueError(f".hair: attribute {key!r} must be ({n},{width if width > 1 else ''}), "
                                 f"got {np.shape(s.attributes[key])}")
            flags |= bit
            per_point.append(np.repeat(a, p, axis=0).astype("<f4").tobytes())
    info = "vid2haircut" + (f"; head_model={s.head_model}" if s.head_model else "")
    info_b = info.encode("utf-8")[:87]
    header = _HAIR_HEADER.pack(b"HAIR", n, n * p, flags, p - 1, 1e-4, 0.0, 0.0, 0.0, 0.0,
                               info_b.ljust(88, b"\0"))
    body = [np.full(n, p - 1, "<u2").tobytes(), s.points.astype("<f4").tobytes()]
    return header + b"".join(body + per_point)
