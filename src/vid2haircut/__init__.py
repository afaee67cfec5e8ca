"""vid2haircut: strand-based 3D hair reconstruction from a monocular head-motion video."""

__version__ = "0.1.0"
