"""A restricted unpickler for model files such as FLAME's ``generic_model.pkl``.

Only plain data may come out of these files: numpy arrays (through numpy's own reconstruction
helpers), scipy sparse matrices, and ``chumpy`` objects, which are mapped to
:class:`ChumpyStub` (a tiny class that only keeps its pickled state and is converted to a plain
array afterwards; chumpy itself is never imported). Every other global -- ``os.system``,
``builtins.eval``, ``subprocess.*`` ... -- is refused before anything runs, with an error naming
the file and the class.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np


class ChumpyStub:
    """Stand-in for any ``chumpy`` class: stores the pickled state, runs no chumpy code."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._stub_args = args

    def __setstate__(self, state: Any) -> None:
        self._stub_state = state

    @property
    def stub_state(self) -> dict:
        state = getattr(self, "_stub_state", None)
        return state if isinstance(state, dict) else {}


def _numpy_helpers() -> dict[str, Any]:
    try:
        from numpy._core import multiarray as ma, numeric as nu  # numpy >= 2
    except ImportError:  # pragma: no cover - numpy 1.x
        from numpy.core import multiarray as ma, numeric as nu
    return {"_reconstruct": ma._reconstruct, "scalar": ma.scalar, "_frombuffer": nu._frombuffer}


_NUMPY_MODULES = {"numpy.core.multiarray", "numpy._core.multiarray", "numpy.core.numeric",
                  "numpy._core.numeric", "numpy"}
_SPARSE_CLASSES = {"csc_matrix", "csr_matrix", "coo_matrix", "csc_array", "csr_array"}


def _object_reconstructor(cls: type, base: type, state: Any) -> Any:
    """Python 2 protocol 0/1 object reconstruction (copy_reg._reconstructor) for allowed classes."""
    if base is not object:
        raise pickle.UnpicklingError(f"reconstruction from base {base!r} is not allowed")
    return object.__new__(cls)


def _latin1_encode(text: str, encoding: str = "latin1") -> bytes:
    """``_codecs.encode`` as Python 3 protocol-2 pickles use it for bytes (latin1 only)."""
    if encoding not in ("latin1", "latin-1") or not isinstance(text, str):
        raise pickle.UnpicklingError(f"codecs.encode with {encoding!r} is not allowed")
    return text.encode("latin1")


class RestrictedUnpickler(pickle.Unpickler):
    """Unpickler whose ``find_class`` allows numpy arrays, scipy sparse matrices and chumpy
    objects (as :class:`ChumpyStub`) and refuses everything else."""

    def __init__(self, file: Any, source: str) -> None:
        super().__init__(file, encoding="latin1")
        self.source = source

    def find_class(self, module: str, name: str) -> Any:  # noqa: D401 - pickle API
        if module == "chumpy" or module.startswith("chumpy."):
            return ChumpyStub
        if module in _NUMPY_MODULES:
            helpers = _numpy_helpers()
            if name in helpers:
                return helpers[name]
            if name in ("ndarray", "dtype"):
                return getattr(np, name)
        if module == "numpy" and name in ("float64", "float32", "int64", "int32", "uint32", "bool_"):
            return getattr(np, name)
        if module.startswith("numpy.dtypes") and name.endswith("DType"):
            import numpy.dtypes

            return getattr(numpy.dtypes, name)
        if (module == "scipy.sparse" or module.startswith("scipy.sparse.")) and name in _SPARSE_CLASSES:
            import scipy.sparse

            return getattr(scipy.sparse, name)
        if module in ("copy_reg", "copyreg") and name == "_reconstructor":
            return _object_reconstructor
        if module == "_codecs" and name == "encode":
            return _latin1_encode
        if module in ("__builtin__", "builtins") and name == "object":
            return object
        raise pickle.UnpicklingError(
            f"{self.source}: refusing to load class {module}.{name} from this pickle (only numpy "
            "arrays, scipy sparse matrices and chumpy arrays are allowed in a model file)")


def safe_load_pickle(path: str | Path) -> Any:
    """Load a pickle through :class:`RestrictedUnpickler` (latin1 for Python 2 files).

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file is not a pickle or refers to a class that is not allowed.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such model file")
    with open(path, "rb") as fh:
        try:
            return RestrictedUnpickler(fh, str(path)).load()
        except pickle.UnpicklingError as e:
            msg = str(e)
            raise ValueError(msg if msg.startswith(str(path)) else f"{path}: not a valid pickle ({msg})") from None
        except (EOFError, AttributeError, ImportError, IndexError, TypeError, KeyError) as e:
            raise ValueError(f"{path}: not a valid model pickle ({type(e).__name__}: {e})") from None


def to_array(obj: Any, what: str = "array") -> np.ndarray:
    """Plain numpy array from an ndarray, a scipy sparse matrix or a :class:`ChumpyStub`.

    Raises ValueError naming ``what`` when a chumpy object carries no stored value.
    """
    if isinstance(obj, ChumpyStub):
        state = obj.stub_state
        if "x" in state:
            return to_array(state["x"], what)
        raise ValueError(f"{what}: chumpy object without a stored value (keys {sorted(state)})")
    if hasattr(obj, "toarray") and callable(obj.toarray):
        return np.asarray(obj.toarray())
    return np.asarray(obj)
