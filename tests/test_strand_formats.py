"""Round trips and error handling of the strand file formats."""

import struct

import numpy as np
import pytest

from vid2haircut.io.strand_formats import load_strands, save_strands
from vid2haircut.strands import StrandSet


def _set(n=6, p=9, seed=0, head="proxy-v1"):
    rng = np.random.default_rng(seed)
    pts = (rng.normal(scale=0.01, size=(n, p, 3)).cumsum(1)).astype(np.float32)
    attrs = {"color": rng.random((n, 3)).astype(np.float32), "width": rng.random(n).astype(np.float32) * 1e-4}
    return StrandSet(pts, attrs, head)


@pytest.mark.parametrize("suffix", [".npz", ".data", ".hair", ".ply"])
def test_round_trip_points_bit_exact(tmp_path, suffix):
    s = _set()
    path = save_strands(tmp_path / f"hair{suffix}", s)
    r = load_strands(path)
    assert r.points.dtype == np.float32 and r.points.shape == s.points.shape
    assert np.array_equal(r.points, s.points)
    if suffix in (".npz", ".hair"):
        assert r.head_model == "proxy-v1"
        for k in ("color", "width"):
            assert np.array_equal(r.attributes[k], s.attributes[k])
    # deterministic bytes, no leftover temporary files
    again = save_strands(tmp_path / "again" / f"hair{suffix}", s)
    if suffix != ".npz":                       # zip members carry timestamps
        assert again.read_bytes() == path.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again", f"hair{suffix}"]
    # resampling on load
    r5 = load_strands(path, n_points=5)
    assert r5.n_points == 5 and np.array_equal(r5.roots, s.roots) and np.array_equal(r5.tips, s.tips)


def test_data_layout_and_variable_length(tmp_path):
    # hand-written USC file: 3 strands with 3, 1 (placeholder) and 2 points
    a = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2]], "<f4")
    b = np.array([[5, 5, 5]], "<f4")
    c = np.array([[1, 0, 0], [1, 0, 4]], "<f4")
    raw = struct.pack("<i", 3) + b"".join(struct.pack("<i", len(x)) + x.tobytes() for x in (a, b, c))
    (tmp_path / "u.data").write_bytes(raw)
    s = load_strands(tmp_path / "u.data")
    assert s.points.shape == (2, 3, 3)                     # placeholder dropped, common count = max
    assert np.array_equal(s.points[0], a)
    np.testing.assert_allclose(s.points[1], [[1, 0, 0], [1, 0, 2], [1, 0, 4]])
    # the writer produces exactly that layout
    out = save_strands(tmp_path / "w.data", StrandSet(a[None]))
    assert out.read_bytes() == struct.pack("<ii", 1, 3) + a.tobytes()


def test_hair_header_layout(tmp_path):
    s = _set(n=2, p=4)
    data = save_strands(tmp_path / "h.hair", s).read_bytes()
    sig, n, total, flags, dseg = struct.unpack_from("<4sIIII", data)
    assert (sig, n, total, dseg) == (b"HAIR", 2, 8, 3)
    assert flags == 1 | 2 | 4 | 16                          # segments, points, thickness, color
    assert len(data) == 128 + 2 * 2 + 8 * 12 + 8 * 4 + 8 * 12
    assert np.array_equal(np.frombuffer(data, "<u2", 2, 128), [3, 3])
    assert np.array_equal(np.frombuffer(data, "<f4", 24, 132).reshape(2, 4, 3), s.points)
    # a file without a segments array uses the default segment count
    header = struct.pack("<4sIIIIff3f88s", b"HAIR", 2, 6, 2, 2, 1.0, 0.0, 0, 0, 0, b"")
    pts = np.arange(18, dtype="<f4").reshape(6, 3)
    (tmp_path / "d.hair").write_bytes(header + pts.tobytes())
    r = load_strands(tmp_path / "d.hair")
    assert np.array_equal(r.points.reshape(6, 3), pts) and r.head_model is None and not r.attributes


def test_ascii_ply_and_unordered_edges(tmp_path):
    text = """ply
format ascii 1.0
comment head_model=proxy-v1
element vertex 5
property float x
property float y
property float z
property uchar red
element edge 3
property int vertex1
property int vertex2
end_header
0 0 0 1
9 9 9 1
0 0 1 1
9 9 8 1
0 0 2 1
2 4
1 3
0 2
"""
    (tmp_path / "a.ply").write_text(text)
    s = load_strands(tmp_path / "a.ply")
    assert s.head_model == "proxy-v1" and s.n_strands == 2 and s.n_points == 3
    np.testing.assert_allclose(s.points[0], [[0, 0, 0], [0, 0, 1], [0, 0, 2]])
    np.testing.assert_allclose(s.points[1], [[9, 9, 9], [9, 9, 8.5], [9, 9, 8]])   # 2 points -> 3
    cyc = text.replace("2 4\n1 3\n0 2\n", "0 2\n2 4\n4 0\n")
    (tmp_path / "c.ply").write_text(cyc)
    with pytest.raises(ValueError, match="c.ply.*(cycle|branch)"):
        load_strands(tmp_path / "c.ply")


@pytest.mark.parametrize("suffix", [".data", ".hair", ".ply"])
def test_truncated_files_name_file_and_offset(tmp_path, suffix):
    path = save_strands(tmp_path / f"t{suffix}", _set(n=3, p=5))
    data = path.read_bytes()
    path.write_bytes(data[:-7])
    with pytest.raises(ValueError, match=rf"t\{suffix}.*byte offset \d+"):
        load_strands(path)
    path.write_bytes(data + b"\0" * 4)
    if suffix != ".ply":                                   # PLY tolerates trailing bytes
        with pytest.raises(ValueError, match=rf"t\{suffix}.*trailing.*byte offset {len(data)}"):
            load_strands(path)


def test_malformed_inputs(tmp_path):
    (tmp_path / "bad.hair").write_bytes(b"HAIX" + bytes(124))
    with pytest.raises(ValueError, match="bad.hair.*signature"):
        load_strands(tmp_path / "bad.hair")
    (tmp_path / "neg.data").write_bytes(struct.pack("<ii", 1, -4))
    with pytest.raises(ValueError, match="neg.data.*negative point count.*byte offset 4"):
        load_strands(tmp_path / "neg.data")
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04garbage")
    with pytest.raises(ValueError, match="bad.npz"):
        load_strands(tmp_path / "bad.npz")
    np.savez(tmp_path / "nopts.npz", foo=np.zeros(3))
    with pytest.raises(ValueError, match="nopts.npz.*'points'"):
        load_strands(tmp_path / "nopts.npz")
    with pytest.raises(ValueError, match="unknown strand file suffix"):
        save_strands(tmp_path / "x.obj", _set())
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        load_strands(tmp_path / "missing.npz")


def test_npz_spec_layout_with_extra_keys(tmp_path):
    # the spec's ground_truth/strands.npz: points, head_model str, frame_points_<t> (N,P,3)
    pts = _set(n=4, p=6).points
    np.savez(tmp_path / "gt.npz", points=pts, head_model=np.array("proxy-v1"),
             frame_points_00003=pts + 1, scalar=np.float32(2.0))
    s = load_strands(tmp_path / "gt.npz")
    assert s.head_model == "proxy-v1" and np.array_equal(s.points, pts)
    assert set(s.attributes) == {"frame_points_00003"}


def test_binary_ply_with_extra_properties_and_list_element(tmp_path):
    # big-endian, a double vertex property first, and a face element with a list property
    xyz = np.array([[0, 0, 0], [0, 1, 0], [0, 2, 0]], ">f4")
    header = ("ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double q\nproperty float x\n"
              "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
              "element edge 2\nproperty int vertex1\nproperty int vertex2\nend_header\n").encode()
    verts = b"".join(np.float64(7).astype(">f8").tobytes() + row.tobytes() for row in xyz)
    face = b"\x03" + np.array([0, 1, 2], ">i4").tobytes()
    edges = np.array([[0, 1], [1, 2]], ">i4").tobytes()
    (tmp_path / "b.ply").write_bytes(header + verts + face + edges)
    s = load_strands(tmp_path / "b.ply")
    assert np.array_equal(s.points[0], xyz.astype(np.float32))
    (tmp_path / "b.ply").write_bytes(header + verts + face[:5])
    with pytest.raises(ValueError, match=r"b.ply.*byte offset \d+"):
        load_strands(tmp_path / "b.ply")
