"""Test-session settings shared by every test module."""

import os

# As in `python -m vid2haircut`: idle OpenMP threads sleep instead of spinning (2 shared cores).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
