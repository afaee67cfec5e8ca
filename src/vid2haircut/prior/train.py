"""Training of the hair prior (a cached pipeline stage): corpus -> codec -> views -> PriorNet.

:func:`train_prior` writes ``codec.npz``, ``prior.pt`` (state_dict + config JSON) and
``prior.json`` (the training record: config, seeds, corpus size, timings, final losses, torch
version; written last, so its presence marks a complete artifact) atomically into ``out_dir``.
A folder that already holds a complete artifact with the same config fingerprint is reused.

Loss per batch (weights in :class:`TrainConfig`):
``w_points * mean |decoded point error| (cm, hair texels of a random texel subset)
+ w_coef * mean squared coefficient error (all scalp texels) + w_mask * BCE(mask logits)``.

Example::

    result = train_prior("resources/prior/default", setting="default", seed=0)
    net, codec, record = load_prior(result.out_dir)
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import platform
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterator, NamedTuple

import numpy as np
import torch

from vid2haircut.io.atomic import atomic_path, write_json
from vid2haircut.prior.codec import StrandCodec
from vid2haircut.prior.corpus import fit_codec
from vid2haircut.prior.losses import LossTerms, LossWeights, augment, prior_losses
from vid2haircut.prior.dataset import DatasetConfig, PriorDataset, build_dataset, load_or_build_corpus
from vid2haircut.prior.model import PRIOR_FILES, PriorConfig, PriorNet
from vid2haircut.prior.scalp import scalp_grid
from vid2haircut.prior.views import ViewConfig

__all__ = ["TrainConfig", "TrainedPrior", "train_prior", "fit_prior_net", "config_fingerprint", "SETTINGS"]

log = logging.getLogger(__name__)
RECORD_FORMAT = "vid2haircut-prior-v1"


@dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a trained prior (its fingerprint decides cache reuse)."""

    model: PriorConfig = field(default_factory=PriorConfig)
    """Network sizes (``model.k`` is also the codec's K)."""
    data: DatasetConfig = field(default_factory=DatasetConfig)
    """Training hairstyles and views."""
    steps: int = 2500
    """Optimiser steps."""
    batch: int = 16
    """Views per step."""
    lr: float = 2e-3
    """Peak AdamW learning rate (linear warm-up, cosine decay to 5%)."""
    weight_decay: float = 1e-4
    """AdamW weight decay."""
    warmup: int = 100
    """Warm-up steps."""
    n_texels: int = 128
    """Texels per view whose decoded strands enter the point loss."""
    w_points: float = 1.0
    """Weight of the decoded point error (cm)."""
    w_coef: float = 0.1
    """Weight of the coefficient L2."""
    w_mask: float = 1.0
    """Weight of the baldness BCE."""
    w_standoff: float = 0.0
    """Weight of the standoff term (cm): the decoded points' distance from the head surface against
    the targets' (:func:`vid2haircut.prior.losses.prior_losses`; 0 = off, as the bundled prior)."""
    shift_px: int = 3
    """Input augmentation: random shift of up to this many pixels."""
    depth_dropout: float = 0.25
    """Input augmentation: probability of removing the depth channels (pipeline runs without depth)."""
    grad_clip: float = 1.0
    """Gradient norm clip."""

    def loss_weights(self) -> LossWeights:
        """The loss weights of this config."""
        return LossWeights(self.w_points, self.w_coef, self.w_mask, self.n_texels, self.w_standoff)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able record (without the standoff weight when it is off, so records and fingerprints
        of priors trained before the term existed stay valid)."""
        d = asdict(self)
        d["model"] = self.model.to_dict()
        d["data"] = self.data.to_dict()
        if not self.w_standoff:
            d.pop("w_standoff")
        return json.loads(json.dumps(d))


SETTINGS: dict[str, TrainConfig] = {
    "default": TrainConfig(data=DatasetConfig(view=ViewConfig(source="photo"))),
    "tiny": TrainConfig(
        model=PriorConfig.tiny(),
        data=DatasetConfig(families=("bob", "long_straight"), train_seeds=(0, 1), strands_per_style=300,
                           views_per_style=2, view=ViewConfig(render_size=64, render_strands=300,
                                                              render_points=12, strand_width=4e-3)),
        steps=150, batch=4, lr=3e-3, warmup=10, n_texels=32, shift_px=2),
    "render": TrainConfig(),
    "render_large": TrainConfig(data=DatasetConfig(train_seeds=tuple(range(24))), steps=5000),
    "standoff": TrainConfig(data=DatasetConfig(view=ViewConfig(source="photo")), w_standoff=2.0),
}
"""Named settings of ``train_prior``: ``default`` (the committed prior: training views made like
the pipeline's targets, i.e. a photo of a dense copy of the style turned into hair coverage, Gabor
orientation and relative depth, :func:`vid2haircut.prior.views.photo_view`), ``tiny`` (tests),
``render`` (the same but trained on direct renders of the strands, :func:`vid2haircut.prior.views.render_view`;
the default before it, kept to measure the gap) and ``render_large`` (``render`` with 3x the
hairstyles and 2x the steps) and ``standoff`` (``default`` with the standoff term at weight 2;
measured worse downstream: Stage 1 0.0913 against 0.0732 on the quality benchmark's first draw).
The README's prior and quality sections give their measured effect."""


def config_fingerprint(cfg: TrainConfig, seed: int) -> str:
    """16 hex digits identifying (config, seed, record format)."""
    blob = json.dumps({"format": RECORD_FORMAT, "config": cfg.to_dict(), "seed": int(seed)}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _lr(step: int, cfg: TrainConfig) -> float:
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    t = (step - cfg.warmup) / max(cfg.steps - cfg.warmup, 1)
    return cfg.lr * (0.05 + 0.95 * 0.5 * (1.0 + math.cos(math.pi * min(t, 1.0))))


def fit_prior_net(data: PriorDataset, codec: StrandCodec, head: Any, cfg: TrainConfig, seed: int = 0,
                  device: torch.device | str = "cpu", progress: bool = True) -> tuple[PriorNet, list[dict]]:
    """Train a :class:`PriorNet` on a dataset (deterministic given ``seed``).

    Returns:
        ``(net, history)``: the trained net (eval mode) and the loss record, one dict per 25 steps
        (``step``, ``total``, ``points_cm``, ``coef``, ``mask_bce`` averaged since the last entry).
    """
    from tqdm.auto import tqdm

    device = torch.device(device)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(seed))
        net = PriorNet(cfg.model)
    net.set_training_means(data.z.mean(0), data.mask.mean(0))
    net.to(device).train()
    codec = codec.to(device)
    grid = scalp_grid(head, cfg.model.map_res)
    valid = torch.as_tensor(grid.index, device=device)
    roots = torch.as_tensor(grid.roots.reshape(-1, 3)[grid.index], dtype=torch.float32, device=device)
    sdf = head.sdf if cfg.w_standoff > 0 else None
    z_all, m_all = data.z.to(device), data.mask.to(device)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    g_cpu = torch.Generator().manual_seed(int(seed) + 1)
    g_dev = torch.Generator(device=device).manual_seed(int(seed) + 2)
    history, acc = [], np.zeros(len(LossTerms._fields))
    weights = cfg.loss_weights()
    bar = tqdm(range(cfg.steps), desc="prior training", disable=not progress, leave=False)
    for step in bar:
        idx = torch.randint(data.n_views, (cfg.batch,), generator=g_cpu)
        x = augment(data.inputs[idx].to(device=device, dtype=torch.float32), cfg.shift_px, cfg.depth_dropout, g_dev)
        sty = data.view_style[idx].to(device)
        for group in opt.param_groups:
            group["lr"] = _lr(step, cfg)
        z, logits = net(x)
        terms = prior_losses(z, logits, z_all[sty], m_all[sty], valid, codec, weights, g_dev, roots, sdf)
        opt.zero_grad(set_to_none=True)
        terms.total.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.grad_clip)
        opt.step()
        acc += [float(t.detach()) for t in terms]
        if (step + 1) % 25 == 0 or step + 1 == cfg.steps:
            n = (step % 25) + 1
            history.append({"step": step + 1, **{k: round(float(v) / n, 6) for k, v in zip(LossTerms._fields, acc)}})
            acc[:] = 0.0
            bar.set_postfix(loss=f"{history[-1]['total']:.3f}", pts_cm=f"{history[-1]['points_cm']:.2f}")
    bar.close()
    return net.eval(), history


class TrainedPrior(NamedTuple):
    """Result of :func:`train_prior`.

    Attributes:
        out_dir: the artifact folder.
        record: the training record (contents of ``prior.json``).
        reused: True when an existing artifact with the same fingerprint was returned untouched.
    """

    out_dir: Path
    record: dict
    reused: bool


def _existing(out_dir: Path, fingerprint: str) -> dict | None:
    if not all((out_dir / f).is_file() for f in PRIOR_FILES):
        return None
    try:
        record = json.loads((out_dir / "prior.json").read_text())
    except (OSError, ValueError):
        return None
    if record.get("fingerprint") != fingerprint:
        return None
    try:
        codec_ok = StrandCodec.load(out_dir / "codec.npz").fingerprint() == record.get("codec_fingerprint")
    except (OSError, ValueError):
        codec_ok = False
    return record if codec_ok else None


def train_prior(out_dir: str | Path, setting: str | TrainConfig = "default", seed: int = 0,
                device: torch.device | str = "cpu", cache_dir: str | Path | None = None,
                progress: bool = True, force: bool = False, num_threads: int | None = 1) -> TrainedPrior:
    """Build the corpus, fit the codec, render views, train the prior, write the artifact.

    Args:
        out_dir: artifact folder (``codec.npz``, ``prior.pt``, ``prior.json``).
        setting: ``"default"``, ``"tiny"`` (see :data:`SETTINGS`) or a :class:`TrainConfig`.
        seed: seed of view poses, initialisation and batches (same seed -> same artifact on a
            given device / torch build).
        device: torch device for training.
        cache_dir: cache of the generated corpus and rendered views (None = a temporary folder,
            removed afterwards).
        progress: tqdm progress bars.
        force: retrain even when a complete artifact with the same fingerprint exists.
        num_threads: torch CPU threads during this call (restored afterwards; None = unchanged).
            Default 1: bitwise reproducible whatever the core count, and much faster than several
            threads for this small net on a busy machine.

    Returns:
        :class:`TrainedPrior`.
    """
    if isinstance(setting, str):
        if setting not in SETTINGS:
            raise ValueError(f"train_prior: unknown setting {setting!r}; known: {sorted(SETTINGS)}")
        cfg = SETTINGS[setting]
    else:
        cfg = setting
    out_dir = Path(out_dir)
    fp = config_fingerprint(cfg, seed)
    record = None if force else _existing(out_dir, fp)
    if record is not None:
        log.info("%s: prior artifact %s is up to date, not retraining", out_dir, fp)
        return TrainedPrior(out_dir, record, True)
    with _torch_threads(num_threads), contextlib.ExitStack() as stack:
        cache = Path(cache_dir) if cache_dir is not None else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        return _train(out_dir, cfg, setting, seed, fp, device, cache, progress)


@contextlib.contextmanager
def _torch_threads(n: int | None) -> Iterator[None]:
    """Temporarily set torch's intra-op CPU threads."""
    old = torch.get_num_threads()
    if n is not None:
        if n < 1:
            raise ValueError(f"num_threads must be >= 1, got {n}")
        torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(old)


def _train(out_dir: Path, cfg: TrainConfig, setting: str | TrainConfig, seed: int, fp: str,
           device: torch.device | str, cache: Path, progress: bool) -> TrainedPrior:
    """The training stage proper (see :func:`train_prior`)."""
    from vid2haircut.head import get_head

    t0 = time.perf_counter()
    head = get_head(cfg.data.head)
    corpus = load_or_build_corpus(cfg.data, cache, head)
    t_corpus = time.perf_counter()
    codec = fit_codec(corpus, k=cfg.model.k, meta={"dataset": cfg.data.to_dict()})
    t_codec = time.perf_counter()
    data = build_dataset(corpus, codec, head, cfg.data, cfg.model.input_size, cfg.model.map_res, seed, cache,
                         progress)
    t_views = time.perf_counter()
    net, history = fit_prior_net(data, codec, head, cfg, seed, device, progress)
    t_train = time.perf_counter()
    last = history[-max(1, min(4, len(history))):]
    record = {
        "format": RECORD_FORMAT, "fingerprint": fp, "setting": setting if isinstance(setting, str) else "custom",
        "seed": int(seed), "config": cfg.to_dict(), "codec_fingerprint": codec.fingerprint(),
        "corpus": {"styles": [list(s) for s in corpus.styles], "n_styles": len(corpus.styles),
                   "n_strands": corpus.n_strands, "n_views": data.n_views,
                   "codec_explained_variance": codec.meta.get("explained_variance")},
        "n_parameters": net.n_parameters(),
        "timings_s": {"corpus": round(t_corpus - t0, 2), "codec": round(t_codec - t_corpus, 2),
                      "views": round(t_views - t_codec, 2), "train": round(t_train - t_views, 2),
                      "per_step": round((t_train - t_views) / max(cfg.steps, 1), 4),
                      "total": round(t_train - t0, 2)},
        "initial_losses": history[0] if history else {},
        "final_losses": {k: float(np.mean([h[k] for h in last])) for k in LossTerms._fields} if history else {},
        "history": history,
        "environment": {"torch": torch.__version__, "numpy": np.__version__, "python": platform.python_version(),
                        "device": str(device), "threads": torch.get_num_threads()},
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "prior.json").unlink(missing_ok=True)   # the completion marker goes first, comes back last
    codec.save(out_dir / "codec.npz")
    state = {k: v.detach().cpu() for k, v in net.state_dict().items()}
    with atomic_path(out_dir / "prior.pt") as tmp:
        torch.save({"config": json.dumps(cfg.model.to_dict(), sort_keys=True), "state_dict": state,
                    "fingerprint": fp}, tmp)
    write_json(out_dir / "prior.json", record)
    log.info("%s: prior trained in %.0f s (final point error %.2f cm)", out_dir, t_train - t0,
             record["final_losses"].get("points_cm", float("nan")))
    return TrainedPrior(out_dir, record, False)

