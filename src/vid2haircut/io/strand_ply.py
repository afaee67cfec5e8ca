"""Strands as PLY polylines: ``vertex`` (x,y,z) plus ``edge`` (vertex1, vertex2) elements.

The writer emits binary little-endian PLY with one vertex per strand point (strand-major, root
first) and edges ``(k, k+1)`` along each strand. The reader takes ASCII and binary (either byte
order) PLY, skips unknown elements and properties, and rebuilds strands by following the
directed edges from vertices that have no incoming edge (the roots). Branching or cyclic edge
sets are rejected.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vid2haircut.strands import StrandSet

__all__ = ["ply_bytes", "read_ply_polylines"]

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def ply_bytes(s: StrandSet) -> bytes:
    """Binary little-endian PLY bytes of a strand set: N*P vertices, N*(P-1) edges."""
    n, p = s.points.shape[:2]
    idx = np.arange(n * p, dtype=np.int64).reshape(n, p)
    edges = np.stack([idx[:, :-1], idx[:, 1:]], -1).reshape(-1, 2).astype("<i4")
    head = f"comment head_model={s.head_model}\n" if s.head_model else ""
    header = (f"ply\nformat binary_little_endian 1.0\ncomment vid2haircut strands: {n} x {p} points\n{head}"
              f"element vertex {n * p}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element edge {len(edges)}\nproperty int vertex1\nproperty int vertex2\nend_header\n")
    return header.encode("ascii") + s.points.astype("<f4").tobytes() + edges.tobytes()


def _parse_header(path: Path, data: bytes) -> tuple[str, list, list[str], int]:
    """Returns (format, elements [(name, count, [(prop, dtype | (count_dt, item_dt))])], comments, body offset)."""
    if not data.startswith(b"ply"):
        raise ValueError(f"{path}: malformed PLY: no 'ply' magic at byte offset 0")
    end = data.find(b"end_header")
    if end < 0:
        raise ValueError(f"{path}: malformed PLY: no 'end_header' line (truncated header, {len(data)} bytes)")
    nl = data.find(b"\n", end)
    body = len(data) if nl < 0 else nl + 1
    fmt, elements, comments = None, [], []
    offset = 0
    for raw in data[:end].split(b"\n"):
        line = raw.decode("ascii", "replace").strip()
        parts = line.split()
        try:
            if not parts or parts[0] in ("ply", "obj_info"):
                pass
            elif parts[0] == "comment":
                comments.append(line[len("comment"):].strip())
            elif parts[0] == "format":
                fmt = parts[1]
            elif parts[0] == "element":
                elements.append((parts[1], int(parts[2]), []))
            elif parts[0] == "property" and parts[1] == "list":
                elements[-1][2].append((parts[4], (_PLY_TYPES[parts[2]], _PLY_TYPES[parts[3]])))
            elif parts[0] == "property":
                elements[-1][2].append((parts[2], _PLY_TYPES[parts[1]]))
            else:
                raise ValueError(line)
        except (IndexError, KeyError, ValueError) as e:
            raise ValueError(f"{path}: malformed PLY header line {line!r} at byte offset {offset}") from e
        offset += len(raw) + 1
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ValueError(f"{path}: unsupported PLY format {fmt!r}")
    return fmt, elements, comments, body


def _read_binary(path: Path, data: bytes, pos: int, elements: list, order: str) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for name, count, props in elements:
        if all(isinstance(t, str) for _, t in props):
            dt = np.dtype([(pn, order + t) for pn, t in props])
            nbytes = dt.itemsize * count
            if pos + nbytes > len(data):
                raise ValueError(f"{path}: truncated PLY at byte offset {pos}: element {name!r} needs "
                                 f"{nbytes} bytes, {len(data) - pos} left")
            rec = np.frombuffer(data, dt, count, pos)
            out[name] = {pn: rec[pn] for pn, _ in props}
            pos += nbytes
            continue
        cols: dict[str, list] = {pn: [] for pn, _ in props}
        for _ in range(count):              # elements with list properties: row by row
            for pn, t in props:
                kinds = t if isinstance(t, tuple) else (None, t)
                if kinds[0] is not None:
                    cdt = np.dtype(order + kinds[0])
                    if pos + cdt.itemsize > len(data):
                        raise ValueError(f"{path}: truncated PLY at byte offset {pos} in element {name!r}")
                    k = int(np.frombuffer(data, cdt, 1, pos)[0])
                    pos += cdt.itemsize
                else:
                    k = 1
                idt = np.dtype(order + kinds[1])
                if pos + idt.itemsize * k > len(data):
                    raise ValueError(f"{path}: truncated PLY at byte offset {pos} in element {name!r}")
                val = np.frombuffer(data, idt, k, pos)
                cols[pn].append(val if kinds[0] is not None else val[0])
                pos += idt.itemsize * k
        out[name] = {pn: (np.array(v) if not isinstance(props[i][1], tuple) else v)
                     for i, (pn, v) in enumerate(cols.items())}
    return out


def _read_ascii(path: Path, data: bytes, pos: int, elements: list) -> dict[str, dict]:
    out: dict[str, dict] = {}
    lines = data[pos:].split(b"\n")
    starts = np.concatenate([[0], np.cumsum([len(ln) + 1 for ln in lines])]) + pos
    li = 0
    for name, count, props in elements:
        rows = []
        while len(rows) < count:
            if li >= len(lines):
                raise ValueError(f"{path}: truncated PLY at byte offset {len(data)}: element {name!r} has "
                                 f"{len(rows)} of {count} rows")
            toks = lines[li].split()
            if toks:
                rows.append((li, toks))
            li += 1
        cols: dict[str, list] = {pn: [] for pn, _ in props}
        for ln, toks in rows:
            k = 0
            try:
                for pn, t in props:
                    if isinstance(t, tuple):
                        m = int(toks[k])
                        cols[pn].append(np.array(toks[k + 1:k + 1 + m], dtype=t[1]))
                        if len(cols[pn][-1]) != m:
                            raise IndexError
                        k += 1 + m
                    else:
                        cols[pn].append(float(toks[k]))
                        k += 1
            except (IndexError, ValueError) as e:
                raise ValueError(f"{path}: malformed PLY row of element {name!r} at byte offset "
                                 f"{starts[ln]}: {lines[ln][:80]!r}") from e
        out[name] = {pn: (np.array(cols[pn], dtype=t) if isinstance(t, str) else cols[pn]) for pn, t in props}
    return out


def _chains(path: Path, n_vertices: int, v1: np.ndarray, v2: np.ndarray) -> np.ndarray:
    """Follow directed edges from their roots: (n_chains, max_len) vertex indices, -1 padded."""
    if len(v1) and (min(v1.min(), v2.min()) < 0 or max(v1.max(), v2.max()) >= n_vertices):
        raise ValueError(f"{path}: malformed PLY: edge vertex index out of range [0,{n_vertices})")
    if np.any(np.bincount(v1, minlength=n_vertices) > 1) or np.any(np.bincount(v2, minlength=n_vertices) > 1):
        raise ValueError(f"{path}: malformed PLY: edges branch (a vertex has two next or two previous vertices)")
    nxt = np.full(n_vertices + 1, -1, np.int64)          # slot n_vertices stays -1 (sink for -1)
    nxt[v1] = v2
    has_in = np.zeros(n_vertices, bool)
    has_in[v2] = True
    cur = np.flatnonzero((nxt[:n_vertices] >= 0) & ~has_in)
    cols = []
    while len(cur) and (cur >= 0).any() and len(cols) <= n_vertices:
        cols.append(cur)
        cur = nxt[np.where(cur >= 0, cur, n_vertices)]
    idx = np.stack(cols, 1) if cols else np.zeros((0, 0), np.int64)
    if int((idx >= 0).sum()) != len(np.union1d(v1, v2)):
        raise ValueError(f"{path}: malformed PLY: edges form a cycle (some edge vertices cannot be reached "
                         f"from a root)")
    return idx


def read_ply_polylines(path: Path) -> tuple[list[np.ndarray], dict[str, np.ndarray], str | None]:
    """Read strands from a PLY file: (polylines list of (P_i,3) float32, attributes {}, head model)."""
    path = Path(path)
    data = path.read_bytes()
    fmt, elements, comments, pos = _parse_header(path, data)
    if fmt == "ascii":
        el = _read_ascii(path, data, pos, elements)
    else:
        el = _read_binary(path, data, pos, elements, "<" if fmt == "binary_little_endian" else ">")
    vert = el.get("vertex")
    if vert is None or not all(k in vert for k in "xyz"):
        raise ValueError(f"{path}: PLY has no vertex element with x, y, z properties")
    edge = el.get("edge")
    if edge is None or "vertex1" not in edge or "vertex2" not in edge:
        raise ValueError(f"{path}: PLY has no 'edge' element with vertex1/vertex2: cannot tell strands apart")
    xyz = np.stack([np.asarray(vert[k], np.float32) for k in "xyz"], -1)
    idx = _chains(path, len(xyz), np.asarray(edge["vertex1"], np.int64), np.asarray(edge["vertex2"], np.int64))
    lengths = (idx >= 0).sum(1)
    polylines = [xyz[row[:m]] for row, m in zip(idx, lengths)]
    head = None
    for c in comments:
        if c.startswith("head_model="):
            head = c.split("=", 1)[1].strip() or None
    return polylines, {}, head
