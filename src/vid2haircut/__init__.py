"""vid2haircut: strand-based 3D hair reconstruction from a monocular head-motion video.

Importing the package sets ``GOMP_SPINCOUNT=10000`` in the environment (unless the environment
already sets it or ``OMP_WAIT_POLICY``, or ``VID2HAIRCUT_OMP_TUNING`` is ``0``). It takes effect
only when torch is imported after vid2haircut (the command line and the workflow do so): torch's
OpenMP workers then spin ~10 k iterations (tens of microseconds) after a parallel torch op
instead of the default 300 k (about a millisecond), the time in which they hold a core that the
renderer's numba kernels need (:mod:`vid2haircut.render.numba_backend`). Measured on the
project's 2-core AMD EPYC: a 4k-strand 256 x 256 render forward+backward 76-88 -> 57-60 ms, and
an 80-step Stage 2 fit 25.4 -> 22.9 s on average (README, Performance).
"""

import os as _os

if (_os.environ.get("VID2HAIRCUT_OMP_TUNING", "1") != "0" and "GOMP_SPINCOUNT" not in _os.environ
        and "OMP_WAIT_POLICY" not in _os.environ):
    _os.environ["GOMP_SPINCOUNT"] = "10000"

__version__ = "0.1.0"
