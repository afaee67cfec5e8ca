"""Head models: the built-in procedural proxy, user-supplied FLAME heads, scalp UV and SDF.

>>> from vid2haircut.head import get_head
>>> head = get_head("proxy-v1")
>>> head.vertices.shape[1], head.landmarks.shape
(3, (68, 3))
"""

from __future__ import annotations

import importlib as _importlib
from typing import TYPE_CHECKING

from vid2haircut.head.landmarks import LANDMARK_GROUPS
from vid2haircut.head.scalp import dirs_to_uv, hairline_theta, texel_uv, uv_to_dirs

HEAD_NAMES = ("proxy-v1",)
# imported on first use (they need torch; the workflow's config check reads HEAD_NAMES without it)
_LAZY = {"HeadModel": "model", "SDFGrid": "sdf", "sdf_lookup": "sdf", "sdf_lookup_np": "sdf",
         "load_flame": "flame", "FlameModel": "flame", "export_head": "export"}
if TYPE_CHECKING:
    from vid2haircut.head.model import HeadModel

__all__ = ["get_head", "HeadModel", "SDFGrid", "LANDMARK_GROUPS", "HEAD_NAMES", "sdf_lookup",
           "sdf_lookup_np", "uv_to_dirs", "dirs_to_uv", "texel_uv", "hairline_theta",
           "load_flame", "FlameModel", "export_head"]


def get_head(name: str = "proxy-v1", scale: float = 1.0, width: float = 1.0, depth: float = 1.0,
             crown: float = 1.0) -> HeadModel:
    """Built-in head model by name, cached per arguments (the same object is returned again).

    Args:
        name: ``"proxy-v1"`` (the procedural head).
        scale, width, depth, crown: multiplicative shape factors in [0.5, 2] (1 = default):
            overall size, ear-to-ear width, front-to-back depth, height of the cranium top.
    """
    if name != "proxy-v1":
        raise ValueError(f"unknown head model {name!r}; known: {', '.join(HEAD_NAMES)} "
                         "(FLAME heads: vid2haircut.head.load_flame(path).as_head_model())")
    from vid2haircut.head.proxy import build_proxy_head

    return build_proxy_head(float(scale), float(width), float(depth), float(crown))


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(_importlib.import_module(f"vid2haircut.head.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'vid2haircut.head' has no attribute {name!r}")
