"""Atomic artifact writes: write to a temporary file in the target folder, then rename.

Every artifact of the pipeline goes through these helpers so that an interrupted stage never
leaves a half-written file behind under its final name.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is renamed onto ``path``.

    ``suffix`` defaults to the target's own suffix, so writers that pick the format from the
    extension (OpenCV, matplotlib) keep working. On error the temporary file is removed and
    the target is left untouched.
    """
    path = Path(path)
    check_outputs([path])  # before any work: os.replace would fail only after it, naming the temporary file
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix if suffix is not None else path.suffix,
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp creates 0600; artifacts get normal permissions
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def blocking_file(folder: str | os.PathLike) -> Path | None:
    """The file that keeps ``folder`` from being a folder (``folder`` itself or its nearest existing
    parent, when that is not a folder), or None."""
    for f in (Path(folder), *Path(folder).parents):
        if f.exists():
            return None if f.is_dir() else f
    return None


def check_outputs(paths) -> None:
    """Raise, naming it, when an output file of ``paths`` cannot be written: an existing folder in its
    place, or a file where one of its folders should be. Stages that write several files call it
    first (a late failure would leave the earlier files replaced and the later ones old)."""
    for path in map(Path, paths):
        if path.is_dir():
            raise IsADirectoryError(f"{path}: is a folder, cannot write the output file there")
        f = blocking_file(path.parent)
        if f is not None:
            raise NotADirectoryError(f"{f}: is a file, cannot hold the output {path}")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Atomically write ``data`` to ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike, text: str) -> None:
    """Atomically write ``text`` (UTF-8) to ``path``."""
    write_bytes(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Atomically write ``obj`` as indented, key-sorted JSON (deterministic bytes)."""
    write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n")


def write_npz(path: str | os.PathLike, compressed: bool = True, **arrays: Any) -> None:
    """Atomically write arrays to an ``.npz`` file."""
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            (np.savez_compressed if compressed else np.savez)(fh, **arrays)


def write_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """Atomically write an image (uint8/uint16, HxW or HxWx3 **RGB**) with OpenCV; format from suffix."""
    import cv2

    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        img = img[:, :, ::-1]
    elif img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, [2, 1, 0, 3]]
    path = Path(path)
    try:
        ok, buf = cv2.imencode(path.suffix, np.ascontiguousarray(img))
    except cv2.error:  # no encoder for the suffix
        ok = False
    if not ok:
        raise OSError(f"{path}: OpenCV could not encode the image as {path.suffix}")
    write_bytes(path, buf.tobytes())


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
