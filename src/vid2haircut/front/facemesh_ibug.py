"""MediaPipe Face Mesh (468 vertices) -> iBUG-68 landmark correspondence.

The 68 iBUG points are defined by their meaning (jaw contour, brows, nose bridge and base, eye
corners and lids, outer and inner lip contours). The Face Mesh package ships no such table, but it
does ship named contours (``face_mesh_connections``: face oval, eyes, brows, lips, nose). We derive
each iBUG point from those contours with the rules of :func:`derive_ibug68_indices`:

- jaw 0-16: the lower part of the face oval between the two points level with the outer eye
  corners, resampled at 17 equal arc-length steps (image-left = subject's right first);
- brows 17-26: the upper chain of each brow contour, outer -> inner (subject's right brow first),
  then inner -> outer on the left brow;
- nose bridge 27-30: the mesh midline from the vertex level with the eye corners to the nose tip
  (the most protruding midline vertex), 4 equal arc-length steps;
- nose base 31-35: the subnasale (lowest midline nose-contour vertex) and the next two vertices
  on each side of the nostril contour;
- eyes 36-47: corners = the extreme vertices of each eye loop; lids at 1/3 and 2/3 of the upper
  and lower chains by arc length (iBUG order: clockwise in the image, starting at the corner
  nearest image-left);
- mouth 48-67: outer and inner lip loops, corners = extreme x, centre = mid arc length, the other
  points at equal arc-length steps.

:data:`IBUG68_FROM_FACEMESH` is the result of that derivation on a near-frontal Face Mesh (the
test suite re-derives it from a detection on ``skimage.data.astronaut()`` and compares).
"""

from __future__ import annotations

import collections

import numpy as np

# Output of derive_ibug68_indices() on a near-frontal detection (see the module docstring).
IBUG68_FROM_FACEMESH: tuple[int, ...] = (
    162, 127, 93, 132, 58, 136, 149, 148, 152, 400, 378, 365, 288, 361, 323, 356, 389,  # jaw
    70, 63, 105, 66, 107, 336, 296, 334, 293, 300,  # brows
    6, 197, 5, 4, 98, 97, 2, 326, 327,  # nose bridge, nose base
    33, 160, 158, 133, 153, 144, 362, 385, 387, 263, 373, 380,  # eyes
    61, 40, 37, 0, 267, 270, 291, 321, 314, 17, 84, 91,  # outer lips
    78, 81, 13, 311, 308, 402, 14, 178,  # inner lips
)


def _graph(edges) -> dict[int, list[int]]:
    adj: dict[int, list[int]] = collections.defaultdict(list)
    for i, j in edges:
        adj[int(i)].append(int(j))
        adj[int(j)].append(int(i))
    return adj


def _walk(adj: dict[int, list[int]], start: int, first: int, stop: int | None = None) -> list[int]:
    """Walk a loop/chain from ``start`` through ``first`` until ``stop`` (inclusive) or back to start."""
    path = [start, first]
    while True:
        cur, prev = path[-1], path[-2]
        if stop is not None and cur == stop:
            return path
        nxt = [n for n in adj[cur] if n != prev]
        if not nxt or nxt[0] == start:
            return path
        path.append(nxt[0])


def _resample(path: list[int], xy: np.ndarray, n: int) -> list[int]:
    """Pick ``n`` vertices of ``path`` nearest to equal arc-length steps (ends included)."""
    p = xy[path]
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    targets = np.linspace(0.0, s[-1], n)
    return [path[int(np.argmin(np.abs(s - t)))] for t in targets]


def _split_loop(adj, xy: np.ndarray, left: int, right: int) -> tuple[list[int], list[int]]:
    """Split a closed loop at two vertices into (upper chain, lower chain), both left -> right."""
    a, b = adj[left][:2]
    c1 = _walk(adj, left, a, right)
    c2 = _walk(adj, left, b, right)
    if xy[c1[1:-1], 1].mean() < xy[c2[1:-1], 1].mean():
        return c1, c2
    return c2, c1


def _loop_vertices(edges) -> list[int]:
    return sorted({int(v) for e in edges for v in e})


def _frontalise(mesh: np.ndarray) -> np.ndarray:
    """Rotate a (468, 3) mesh so the eye-corner line is the x axis and the face looks along -z.

    Uses the outer eye corners (33, 263), the nasion-to-chin midline (168, 152) as anchors: these
    four vertex ids are the only ones taken on faith (the Face Mesh canonical topology).
    """
    if mesh.shape[1] < 3:
        return mesh
    ex = mesh[263] - mesh[33]
    ex /= np.linalg.norm(ex)
    down = mesh[152] - mesh[168]
    ey = down - ex * (down @ ex)
    ey /= np.linalg.norm(ey)
    ez = np.cross(ex, ey)
    return (mesh - mesh.mean(axis=0)) @ np.stack([ex, ey, ez]).T


def derive_ibug68_indices(mesh: np.ndarray) -> tuple[int, ...]:
    """Derive the 68 Face Mesh vertex indices of the iBUG points from one near-frontal mesh.

    Args:
        mesh: (468, 2+) Face Mesh vertices in image coordinates (x right, y down; an optional
            third column is depth, smaller = closer to the camera).
    Returns:
        68 vertex indices in iBUG order.
    """
    from mediapipe.python.solutions import face_mesh_connections as fmc

    mesh = _frontalise(np.asarray(mesh, dtype=np.float64))
    xy = mesh[:, :2]
    out: list[int] = []

    # Eyes first (their corners set the jaw's end level).
    eyes = []
    for edges in (fmc.FACEMESH_RIGHT_EYE, fmc.FACEMESH_LEFT_EYE):  # subject's right = image left
        adj = _graph(edges)
        vs = _loop_vertices(edges)
        left = min(vs, key=lambda v: xy[v, 0])
        right = max(vs, key=lambda v: xy[v, 0])
        upper, lower = _split_loop(adj, xy, left, right)
        u = _resample(upper, xy, 4)
        lo = _resample(lower, xy, 4)
        # clockwise in the image from the image-left corner: corner, upper 1/3, upper 2/3, corner,
        # lower 2/3, lower 1/3.
        eyes.append([u[0], u[1], u[2], u[3], lo[2], lo[1]])
    eye_level = 0.5 * (xy[eyes[0][0], 1] + xy[eyes[1][3], 1])

    # Jaw: lower face oval between the points level with the outer eye corners.
    adj = _graph(fmc.FACEMESH_FACE_OVAL)
    oval = _loop_vertices(fmc.FACEMESH_FACE_OVAL)
    cx = xy[oval, 0].mean()
    left_side = [v for v in oval if xy[v, 0] < cx]
    right_side = [v for v in oval if xy[v, 0] >= cx]
    j0 = min(left_side, key=lambda v: abs(xy[v, 1] - eye_level))
    j16 = min(right_side, key=lambda v: abs(xy[v, 1] - eye_level))
    a, b = adj[j0][:2]
    c1, c2 = _walk(adj, j0, a, j16), _walk(adj, j0, b, j16)
    jaw = c1 if xy[c1, 1].mean() > xy[c2, 1].mean() else c2
    out += _resample(jaw, xy, 17)

    # Brows: upper chain of each loop; right brow outer->inner, left brow inner->outer.
    for k, edges in enumerate((fmc.FACEMESH_RIGHT_EYEBROW, fmc.FACEMESH_LEFT_EYEBROW)):
        adj = _graph(edges)
        ends = [v for v, n in adj.items() if len(n) == 1]
        if len(ends) == 2:  # two separate chains (upper and lower edge), each with 2 ends
            pass
        chains = []
        seen: set[int] = set()
        for e in sorted(ends, key=lambda v: xy[v, 0]):
            if e in seen:
                continue
            ch = _walk(adj, e, adj[e][0])
            seen.update(ch)
            chains.append(ch)
        upper = min(chains, key=lambda ch: xy[ch, 1].mean())
        upper = sorted(upper, key=lambda v: xy[v, 0])  # image left -> right
        out += _resample(upper, xy, 5)

    # Nose bridge: midline from eye level to the tip.
    nose = _loop_vertices(fmc.FACEMESH_NOSE)
    width = xy[eyes[1][3], 0] - xy[eyes[0][0], 0]
    mid_x = 0.5 * (xy[eyes[0][3], 0] + xy[eyes[1][0], 0])
    midline = [v for v in nose if abs(xy[v, 0] - mid_x) < 0.04 * width]
    depth = mesh[:, 2] if mesh.shape[1] > 2 else -xy[:, 1]
    tip = min(midline, key=lambda v: depth[v])
    top = min(midline, key=lambda v: abs(xy[v, 1] - eye_level))
    bridge = sorted([v for v in midline if xy[top, 1] <= xy[v, 1] <= xy[tip, 1]], key=lambda v: xy[v, 1])
    out += _resample(bridge, xy, 4)

    # Nose base: subnasale and two steps along the nostril contour each side.
    nadj = _graph(fmc.FACEMESH_NOSE)
    sub = max(midline, key=lambda v: xy[v, 1])
    sides = sorted(nadj[sub], key=lambda v: xy[v, 0])
    base_l = _walk(nadj, sub, sides[0])[:3]
    base_r = _walk(nadj, sub, sides[-1])[:3]
    out += [base_l[2], base_l[1], sub, base_r[1], base_r[2]]

    for e in eyes:
        out += e

    # Lips: outer loop and inner loop.
    ladj = _graph(fmc.FACEMESH_LIPS)
    lips = _loop_vertices(fmc.FACEMESH_LIPS)
    comps: list[list[int]] = []
    seen = set()
    for v in lips:
        if v in seen:
            continue
        stack, comp = [v], []
        while stack:
            w = stack.pop()
            if w in seen:
                continue
            seen.add(w)
            comp.append(w)
            stack += ladj[w]
        comps.append(comp)
    outer, inner = sorted(comps, key=lambda c: -np.ptp(xy[c, 1]))
    for comp, n_up, n_lo in ((outer, 7, 7), (inner, 5, 5)):
        left = min(comp, key=lambda v: xy[v, 0])
        right = max(comp, key=lambda v: xy[v, 0])
        upper, lower = _split_loop(ladj, xy, left, right)
        u = _resample(upper, xy, n_up)
        lo = _resample(lower, xy, n_lo)
        # iBUG: corner, upper left->right, corner, lower right->left (clockwise in the image).
        out += u + lo[::-1][1:-1]

    if len(out) != 68:
        raise AssertionError(f"derived {len(out)} iBUG points, expected 68")
    return tuple(int(v) for v in out)
