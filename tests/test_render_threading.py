"""The numba threading layer of the renderer's kernels: TBB where its library loads (the ``tbb``
package that environment.lock installs), and the same renders and gradients on either layer."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vid2haircut.render.numba_backend import numba_available, tbb_layer_usable

HERE = Path(__file__).resolve().parent

# renders a fixed scene forward and backward with both compositing models (several tiles, both
# threads busy) and saves every output and gradient; prints the layer the kernels ran on
SCRIPT = """
import sys
sys.path.insert(0, {here!r})
import numpy as np, torch
import vid2haircut
import numba
import render_scenes as tr
from vid2haircut.render import render_strands
torch.set_num_threads(2)
out = {{}}
for comp in ("bins", "exact"):
    pts = torch.tensor(tr.random_scene(7, n=150, p=10, spread=0.02), requires_grad=True)
    K, E = tr.orbit_camera(96)
    r = render_strands(pts, torch.tensor(K), torch.tensor(E), 96, 96, compositing=comp)
    (r.silhouette.sum() + r.depth_normalized.sum() + r.direction.sum()).backward()
    for name in ("silhouette", "direction", "depth", "depth_normalized", "mask", "visibility"):
        out[comp + "_" + name] = getattr(r, name).detach().numpy()
    out[comp + "_grad"] = pts.grad.numpy()
np.savez(sys.argv[1], **out)
print(numba.threading_layer())
"""


def _render_in(layer: str, path: Path) -> dict:
    env = {**os.environ, "NUMBA_THREADING_LAYER": layer}
    res = subprocess.run([sys.executable, "-c", SCRIPT.format(here=str(HERE)), str(path)], env=env,
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.split()[-1] == layer
    with np.load(path) as f:
        return {k: f[k] for k in f.files}


@pytest.mark.skipif(not numba_available(), reason="needs numba")
def test_tbb_layer_is_chosen_where_it_loads():
    """On Linux x86-64 the installed tbb package's library loads (the package declares it there),
    and the kernels then run on numba's TBB layer, unless the environment names a layer."""
    import numba

    if sys.platform.startswith("linux") and platform.machine() == "x86_64":
        assert tbb_layer_usable()
    if "NUMBA_THREADING_LAYER" not in os.environ:
        assert numba.config.THREADING_LAYER == ("tbb" if tbb_layer_usable() else "workqueue")


@pytest.mark.skipif(not (numba_available() and tbb_layer_usable()), reason="needs numba and TBB")
def test_renders_are_the_same_on_both_threading_layers(tmp_path):
    """Every channel, the visibility and the point gradients of both compositing models, byte for
    byte, on the TBB and the workqueue layer (no kernel reduces across a parallel loop's
    iterations, so the layer's scheduling cannot change a sum's order)."""
    a = _render_in("tbb", tmp_path / "tbb.npz")
    b = _render_in("workqueue", tmp_path / "workqueue.npz")
    assert a.keys() == b.keys() and len(a) == 14
    for key in a:
        assert a[key].tobytes() == b[key].tobytes(), key
    assert a["exact_mask"].sum() > 200 and np.abs(a["bins_grad"]).sum() > 0
