"""argparse ``type=`` checks shared by the sub-commands: a bad option value is refused before any
work starts, with argparse's one-line usage error naming the option (exit status 2)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def _bounded(convert, noun: str, fmt, lo, hi):
    """An argparse type: ``convert(text)`` (float or int) in [lo, hi], finite (``hi`` None: no upper
    bound); the error names ``noun`` and the range."""
    want = f"{noun} >= {fmt(lo)}" if hi is None else f"{noun} in [{fmt(lo)}, {fmt(hi)}]"

    def check(text: str):
        try:
            v = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {want}, got {text!r}") from None
        if not (lo <= v and (v <= hi if hi is not None else v < math.inf)):  # NaN fails the first test
            raise argparse.ArgumentTypeError(f"expected {want}, got {v if convert is int else text}")
        return v
    return check


def bounded_float(lo: float, hi: float | None = None):
    """A finite number in [lo, hi] (``hi`` None: no upper bound)."""
    return _bounded(float, "a finite number" if hi is None else "a number", lambda x: f"{x:g}", lo, hi)


nonneg_float = bounded_float(0.0)
"""A finite number >= 0."""
unit_float = bounded_float(0.0, 1.0)
"""A number in [0, 1]."""


def device(text: str) -> str:
    """A torch device this machine has: ``cpu``, or ``cuda`` / ``cuda:N`` where CUDA is available."""
    import torch

    try:
        dev = torch.device(text)
    except (RuntimeError, ValueError):
        raise argparse.ArgumentTypeError(f"not a torch device: {text!r} (use cpu, cuda or cuda:N)") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise argparse.ArgumentTypeError(f"{text}: CUDA is not available in this torch build / on this machine "
                                             f"(torch {torch.__version__}); use cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise argparse.ArgumentTypeError(f"{text}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    elif dev.type != "cpu":
        raise argparse.ArgumentTypeError(f"unsupported device {text!r} (use cpu, cuda or cuda:N)")
    return text


def image_path(text: str) -> str:
    """An output image path whose suffix names a format the image writer has (.png, .jpg)."""
    if Path(text).suffix.lower() not in IMAGE_SUFFIXES:
        raise argparse.ArgumentTypeError(f"{text}: the image format comes from the suffix, one of "
                                         f"{', '.join(IMAGE_SUFFIXES)}")
    return text


def bounded_int(lo: int, hi: int | None = None):
    """An integer in [lo, hi] (``hi`` None: no upper bound)."""
    return _bounded(int, "a whole number", str, lo, hi)


nonneg_int = bounded_int(0)
"""An integer >= 0."""


def file_stem(text: str) -> str:
    """A bare file name stem: no folder part (it may not lead outside the output folder)."""
    if not text or Path(text).name != text or text in (".", ".."):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a file name stem without a folder part")
    return text


def out_folder(text: str) -> str:
    """An output folder: absent (it is created) or an existing folder, not a file."""
    from vid2haircut.io.atomic import blocking_file

    f = blocking_file(text)
    if f is not None:
        raise argparse.ArgumentTypeError(f"{f}: is a file, cannot hold the output folder {text}")
    return text
