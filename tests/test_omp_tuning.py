"""The package's OpenMP spin setting (vid2haircut/__init__.py): set on import unless the user chose."""

from __future__ import annotations

import os
import subprocess
import sys


def _spincount(env_extra: dict) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY",
                                                             "VID2HAIRCUT_OMP_TUNING")}
    env.update(env_extra)
    code = "import os, vid2haircut, torch; print(os.environ.get('GOMP_SPINCOUNT', 'unset'))"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()


def test_spincount_set_on_import_unless_chosen_or_disabled():
    assert _spincount({}) == "10000"
    assert _spincount({"GOMP_SPINCOUNT": "123"}) == "123"
    assert _spincount({"OMP_WAIT_POLICY": "PASSIVE"}) == "unset"
    assert _spincount({"VID2HAIRCUT_OMP_TUNING": "0"}) == "unset"
