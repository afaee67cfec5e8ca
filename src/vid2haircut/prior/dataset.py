"""Training set of the hair prior: generated hairstyles -> (rendered view inputs, hair-map targets).

Every family x training seed gives one hairstyle (:mod:`vid2haircut.prior.corpus`); the codec is
fitted on all of their strands; each hairstyle is encoded into its hair map (the target) and
rendered from ``views_per_style`` random frontal-ish poses (:mod:`vid2haircut.prior.views`) into
network inputs. Both stages are cached as ``.npz`` files keyed by a hash of their recipe.

Example::

    cfg = DatasetConfig(train_seeds=(0, 1), views_per_style=2)
    corpus = load_or_build_corpus(cfg, cache_dir)
    data = build_dataset(corpus, codec, head, cfg, input_size=128, map_res=32, seed=0)
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from vid2haircut.io.atomic import write_npz
from vid2haircut.prior.codec import StrandCodec
from vid2haircut.prior.corpus import Corpus, build_corpus, load_corpus, resolve_families, save_corpus
from vid2haircut.prior.hairmap import encode_strands
from vid2haircut.prior.views import (INPUT_CHANNELS, ViewConfig, prior_input, random_pose, training_view,
                                    view_strands)

__all__ = ["DatasetConfig", "PriorDataset", "load_or_build_corpus", "build_dataset", "recipe_hash"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DatasetConfig:
    """Which hairstyles and views make the prior's training set."""

    families: tuple[str, ...] | None = None
    """Generator families (None = all of ``FAMILIES``)."""
    train_seeds: tuple[int, ...] = tuple(range(8))
    """Generator seeds of the training hairstyles (evaluation uses seeds >= 1000)."""
    strands_per_style: int = 1500
    """Strands generated per hairstyle."""
    n_points: int = 100
    """Points per strand."""
    views_per_style: int = 5
    """Rendered training views per hairstyle."""
    view: ViewConfig = field(default_factory=ViewConfig)
    """Pose and rendering settings of the views."""
    head: str = "proxy-v1"
    """Head model name (``vid2haircut.head.get_head``)."""

    def families_or_all(self) -> tuple[str, ...]:
        """The configured families or every generator family."""
        return resolve_families(self.families)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able record (families resolved)."""
        d = asdict(self)
        d["families"] = list(self.families_or_all())
        if self.view.source == "render":      # the photo settings do not apply: records (and fingerprints)
            for key in ("source", "photo_strands", "photo_size"):   # stay those of direct-render priors
                d["view"].pop(key)
        return json.loads(json.dumps(d))


def recipe_hash(obj: Any) -> str:
    """12 hex digits of a SHA-256 over the key-sorted JSON of ``obj``."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:12]


class PriorDataset(NamedTuple):
    """In-memory training set.

    Attributes:
        inputs: (V, C, S, S) float16 network inputs of all views.
        view_style: (V,) int64 style index of each view.
        z: (NS, K, R, R) float32 target coefficient maps, one per style.
        mask: (NS, R, R) float32 target baldness masks.
        styles: ``(family, seed)`` of each style.
    """

    inputs: torch.Tensor
    view_style: torch.Tensor
    z: torch.Tensor
    mask: torch.Tensor
    styles: tuple[tuple[str, int], ...]

    @property
    def n_views(self) -> int:
        """Number of views V."""
        return int(self.inputs.shape[0])


def load_or_build_corpus(cfg: DatasetConfig, cache_dir: str | Path | None = None, head: Any = None) -> Corpus:
    """Generate the training hairstyles, or read them from ``cache_dir`` when the recipe matches."""
    recipe = {"families": list(cfg.families_or_all()), "seeds": list(cfg.train_seeds),
              "strands": cfg.strands_per_style, "points": cfg.n_points, "head": cfg.head}
    path = None if cache_dir is None else Path(cache_dir) / f"corpus_{recipe_hash(recipe)}.npz"
    if path is not None and path.is_file():
        try:
            return load_corpus(path)
        except ValueError as exc:  # a damaged cache is rebuilt, never trusted
            log.warning("%s: ignoring unreadable corpus cache (%s)", path, exc)
    corpus = build_corpus(cfg.families_or_all(), cfg.train_seeds, cfg.strands_per_style, cfg.n_points, head)
    if path is not None:
        save_corpus(path, corpus)
    return corpus


def _targets(corpus: Corpus, codec: StrandCodec, head: Any, map_res: int) -> tuple[torch.Tensor, torch.Tensor]:
    zs, masks = [], []
    for i in range(len(corpus.styles)):
        hm = encode_strands(corpus.strand_set(i), head, codec, res=map_res)
        zs.append(hm.z)
        masks.append(hm.mask)
    return torch.stack(zs), torch.stack(masks)


def _render_inputs(corpus: Corpus, head: Any, cfg: DatasetConfig, input_size: int, seed: int,
                   progress: bool) -> tuple[np.ndarray, np.ndarray]:
    from tqdm.auto import tqdm

    n_styles, n_views = len(corpus.styles), int(cfg.views_per_style)
    inputs = np.zeros((n_styles * n_views, len(INPUT_CHANNELS), input_size, input_size), np.float16)
    style = np.repeat(np.arange(n_styles), n_views)
    bar = tqdm(total=n_styles * n_views, desc="prior views", disable=not progress, leave=False)
    for i in range(n_styles):
        family, style_seed = corpus.styles[i]
        pts = view_strands(corpus.strand_set(i).points, family, style_seed, cfg.view, cfg.n_points, head)
        for v in range(n_views):
            ss = np.random.SeedSequence([int(seed), 7919, i, v])
            rng = np.random.default_rng(ss)
            pose = random_pose(rng, cfg.view)
            maps = training_view(pts, head, pose, cfg.view, int(rng.integers(2 ** 31)))
            x = prior_input(*maps.as_tuple(), maps.K, maps.world_2_cam, pose, size=input_size)
            inputs[i * n_views + v] = x[0].numpy().astype(np.float16)
            bar.update(1)
    bar.close()
    return inputs, style


def build_dataset(corpus: Corpus, codec: StrandCodec, head: Any, cfg: DatasetConfig, input_size: int,
                  map_res: int, seed: int = 0, cache_dir: str | Path | None = None,
                  progress: bool = True) -> PriorDataset:
    """Hair-map targets and rendered view inputs of every corpus hairstyle.

    Args:
        corpus: training hairstyles (:func:`load_or_build_corpus`).
        codec: fitted codec (its K sets the target channels).
        head: head model of the corpus.
        cfg: dataset settings (views per style, view rendering).
        input_size: crop side S of :func:`prior_input`.
        map_res: hair map resolution R.
        seed: seed of the view poses (view ``v`` of style ``i`` uses ``SeedSequence([seed, 7919, i, v])``).
        cache_dir: where rendered inputs are cached (None = no cache).
        progress: show a tqdm bar while rendering.

    Returns:
        :class:`PriorDataset` (targets on the CPU).
    """
    z, mask = _targets(corpus, codec, head, map_res)
    recipe = {"styles": [list(s) for s in corpus.styles], "strands": int(corpus.n_strands),
              "view": cfg.to_dict()["view"], "views": cfg.views_per_style, "size": input_size, "seed": seed,
              "head": cfg.head, "points_sum": float(np.float64(corpus.points[::97].sum())),
              "channels": list(INPUT_CHANNELS)}
    path = None if cache_dir is None else Path(cache_dir) / f"views_{recipe_hash(recipe)}.npz"
    inputs = style = None
    if path is not None and path.is_file():
        try:
            with np.load(path, allow_pickle=False) as d:
                inputs, style = d["inputs"], d["view_style"]
        except (OSError, KeyError, ValueError) as exc:
            log.warning("%s: ignoring unreadable view cache (%s)", path, exc)
    if inputs is None:
        inputs, style = _render_inputs(corpus, head, cfg, input_size, seed, progress)
        if path is not None:
            write_npz(path, inputs=inputs, view_style=style)
    return PriorDataset(torch.from_numpy(np.ascontiguousarray(inputs)), torch.from_numpy(style.astype(np.int64)),
                        z.float(), mask.float(), corpus.styles)
