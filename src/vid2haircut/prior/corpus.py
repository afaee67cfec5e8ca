"""Training / held-out corpora of procedural strands for the strand codec and the hair prior.

A corpus is built from the hairstyle generator (``vid2haircut.synth.hairstyles``): every family x
every seed gives one hairstyle of ``strands_per_style`` strands of ``n_points`` points. The codec
is fitted on the training seeds and judged on held-out seeds (disjoint by construction).

Example::

    cfg = CorpusConfig(train_seeds=(0, 1, 2), test_seeds=(1000,), strands_per_style=2000)
    train = build_corpus(cfg.families_or_all(), cfg.train_seeds, cfg.strands_per_style)
    codec = fit_codec(train, k=64)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np

from vid2haircut.io.atomic import write_npz
from vid2haircut.prior.codec import StrandCodec
from vid2haircut.strands import StrandSet

__all__ = ["CorpusConfig", "Corpus", "build_corpus", "fit_codec", "generate_style", "save_corpus",
           "load_corpus"]


def resolve_families(families: Sequence[str] | None) -> tuple[str, ...]:
    """``families`` as a tuple, or every generator family when None."""
    if families is not None:
        return tuple(families)
    from vid2haircut.synth.hairstyles import FAMILIES

    return tuple(FAMILIES)


@dataclass(frozen=True)
class CorpusConfig:
    """Which hairstyles make a corpus."""

    families: tuple[str, ...] | None = None
    """Generator families; None = all of ``FAMILIES``."""
    train_seeds: tuple[int, ...] = (0, 1, 2, 3)
    """Seeds used for fitting."""
    test_seeds: tuple[int, ...] = (1000, 1001)
    """Held-out seeds (must not overlap ``train_seeds``)."""
    strands_per_style: int = 2000
    """Strands generated per hairstyle."""
    n_points: int = 100
    """Points per strand."""
    head: str = "proxy-v1"
    """Head model name passed to ``get_head``."""

    def __post_init__(self) -> None:
        overlap = set(self.train_seeds) & set(self.test_seeds)
        if overlap:
            raise ValueError(f"CorpusConfig: train and test seeds overlap: {sorted(overlap)}")
        if self.strands_per_style < 1 or self.n_points < 2:
            raise ValueError("CorpusConfig: strands_per_style must be >= 1 and n_points >= 2")

    def families_or_all(self) -> tuple[str, ...]:
        """The configured families, or every generator family."""
        return resolve_families(self.families)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able record (for the codec's meta / training records)."""
        d = asdict(self)
        d["families"] = list(self.families_or_all())
        return d


class Corpus(NamedTuple):
    """Strands of several generated hairstyles, concatenated.

    Attributes:
        points: (N,P,3) float32 strands, root first.
        uv: (N,2) float32 scalp UV of the roots.
        style: (N,) int64 index into ``styles``.
        styles: one ``(family, seed)`` per hairstyle.
    """

    points: np.ndarray
    uv: np.ndarray
    style: np.ndarray
    styles: tuple[tuple[str, int], ...]

    @property
    def n_strands(self) -> int:
        """Number of strands N."""
        return int(self.points.shape[0])

    def family_index(self, family: str) -> np.ndarray:
        """(n,) int64 strand indices of all styles of ``family``."""
        ids = [i for i, (f, _) in enumerate(self.styles) if f == family]
        return np.flatnonzero(np.isin(self.style, ids))

    def strand_set(self, i: int) -> StrandSet:
        """Hairstyle ``i`` as a :class:`StrandSet` with its ``"uv"`` attribute."""
        sel = np.flatnonzero(self.style == i)
        return StrandSet(self.points[sel], {"uv": self.uv[sel]})


def generate_style(family: str, seed: int, n_strands: int, n_points: int = 100, head: Any = None) -> StrandSet:
    """One generated hairstyle, resampled to ``n_points`` (thin wrapper over the generator)."""
    from vid2haircut.synth.hairstyles import FAMILIES, generate_hairstyle

    if family not in FAMILIES:
        raise ValueError(f"unknown hairstyle family {family!r}; known: {sorted(FAMILIES)}")
    s = generate_hairstyle(family, int(seed), head=head, n_strands=int(n_strands), n_points=int(n_points))
    return s.resample(n_points)


def build_corpus(families: Sequence[str], seeds: Sequence[int], strands_per_style: int = 2000,
                 n_points: int = 100, head: Any = None) -> Corpus:
    """Generate every family x seed and concatenate.

    Args:
        families: generator family names.
        seeds: generator seeds.
        strands_per_style: strands per hairstyle.
        n_points: points per strand.
        head: head model passed to the generator (None = its default head).

    Returns:
        :class:`Corpus` with ``len(families) * len(seeds)`` styles (deterministic).
    """
    from vid2haircut.prior.scalp import points_to_scalp_uv

    pts, uvs, style, styles = [], [], [], []
    for fam in families:
        for seed in seeds:
            s = generate_style(fam, seed, strands_per_style, n_points, head)
            uv = s.attributes.get("uv")
            if uv is None or np.shape(uv) != (s.n_strands, 2):
                uv = points_to_scalp_uv(s.roots, getattr(head, "center", None))
            pts.append(s.points)
            uvs.append(np.asarray(uv, np.float32))
            style.append(np.full(s.n_strands, len(styles), np.int64))
            styles.append((str(fam), int(seed)))
    if not styles:
        raise ValueError("build_corpus: no families or no seeds given")
    return Corpus(np.concatenate(pts), np.concatenate(uvs), np.concatenate(style), tuple(styles))


def fit_codec(corpus: Corpus, k: int = 64, meta: dict | None = None) -> StrandCodec:
    """Fit a :class:`StrandCodec` on a corpus (its style list is recorded in the codec's meta)."""
    record = {"corpus_styles": [list(s) for s in corpus.styles], "corpus_strands": corpus.n_strands}
    return StrandCodec.fit(corpus.points, k=k, meta={**record, **(meta or {})})


def save_corpus(path: str | Path, corpus: Corpus) -> None:
    """Atomically write a corpus to an ``.npz`` (float32 points, for caching generated styles)."""
    write_npz(path, points=corpus.points, uv=corpus.uv, style=corpus.style,
              families=np.array([f for f, _ in corpus.styles]),
              seeds=np.array([s for _, s in corpus.styles], np.int64))


def load_corpus(path: str | Path) -> Corpus:
    """Read a corpus written by :func:`save_corpus`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: corpus file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in ("points", "uv", "style", "families", "seeds")}
    except (KeyError, ValueError, OSError) as exc:
        raise ValueError(f"{path}: not a strand corpus .npz ({exc})") from exc
    styles = tuple((str(f), int(s)) for f, s in zip(data["families"], data["seeds"]))
    if data["points"].ndim != 3 or len(data["style"]) != len(data["points"]):
        raise ValueError(f"{path}: inconsistent corpus arrays")
    return Corpus(data["points"].astype(np.float32), data["uv"].astype(np.float32),
                  data["style"].astype(np.int64), styles)
