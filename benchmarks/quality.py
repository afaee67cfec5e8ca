"""Table-1 style quality benchmark: prior alone, Stage 1, Stage 2 and its ablations on generated sequences.

For each (family, seed) of a small fixed set (seeds >= 1000, not used to train the prior; hair
motion on) it synthesises the sequence, runs the front stages (keyframes, head fit, targets) and
then the fitting variants through the same file-level entry points as the pipeline:

- ``oracle``: the ground truth itself encoded into the hair map (nearest strand per texel, the
  same dense decoding as Stage 2's output, carved with its keyframes): the floor of the
  representation, not a method,
- ``prior``: the prior network's prediction on the reference keyframe (no optimisation),
- ``stage1``: single-view fit (Im2Haircut baseline; the default optimises Z from the prior's
  prediction, ``stage1_ft`` fine-tunes the prior network as published),
- ``stage2``: the full method (6 keyframes), and the ablations ``no_deformation``,
  ``no_smoothness``, ``no_visibility``, ``no_pca``, ``kf1``, ``kf3``, ``segment_gate`` (the
  visibility gate per segment, as method.md words it, instead of per strand; these start from the
  default Stage 1), ``stage2_ft`` (the full method started from ``stage1_ft``) and ``stage2_oracle`` (the
  full method started from ``oracle``: how far the Stage 2 objective moves the truth, and which
  final loss the truth reaches against the fits; neither is in the default list).

Each result is scored against the ground truth (Chamfer_pts in m^2, Chamfer_angle in rad; see
``shared/docs/method.md``) and a Markdown table is printed (and written to ``--out`` when given),
followed by the mean Chamfer_pts of each variant split by head region (front / side / back; at
the generator's default the keyframes turn the head up to ~64 degrees, so the back is never seen;
``--yaw-max`` turns it further) and by the median tip height
of the strands rooted in each region against the ground truth's (hair that is too short ends too
high). ``--sway-gain`` sets how
strongly the hair lags the head (``SynthConfig.sway_gain``; the generator default is 0.012, the
README table uses 0.03 so that the deformation has something to explain).
``--stage2-seeds 0,1`` runs the full method and its four switch ablations once per Stage 2 seed
(deformation field, frame codes and dense roots; Stage 1 is shared) and reports their mean, plus a
table of the per-seed means and in how many seeds each ablation is worse than the full method:
the ablations' effects are of the size of the seed-to-seed spread.
The tables are written by ``quality_report.py``. Every stage's outputs are cached under
``--work``: a second run only redoes what is missing, so the benchmark can be run in pieces
(``--sequences``, ``--variants``); ``--jobs 2 --threads 1`` runs it as two processes, one per
sequence and Stage 2 variant at a time.

    .venv/bin/python benchmarks/quality.py --work results/benchmarks/quality --out results/benchmarks/quality.md
    .venv/bin/python benchmarks/quality.py --sway-gain 0.03 --work results/benchmarks/quality_sway \
        --out results/benchmarks/quality_sway.md        # the README table
    .venv/bin/python benchmarks/quality.py --quick        # 2 sequences, short schedules (smoke run)
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

from quality_report import (LABELS, emit, loss_table, region_bound, region_table, seed_table, table, tip_table,
                            unseen_bound)
from quality_data import HEAD_FILL, SEQUENCES, SWAY_GAIN, YAW_MAX, parse_sequence, prepare
from quality_jobs import run_jobs
from quality_score import score, unseen_test

STAGE2_VARIANTS = {
    "stage2": {},
    "no_deformation": {"switches": {"use_deformation": False}},
    "no_smoothness": {"switches": {"use_smoothness": False}},
    "no_visibility": {"switches": {"use_visibility": False}},
    "no_pca": {"switches": {"use_pca_consistency": False}},
    "segment_gate": {"visibility_unit": "segment"},
    "kf1": {"n_keyframes": 1},
    "kf3": {"n_keyframes": 3},
    "stage2_ft": {},
    "stage2_oracle": {},
}
SEEDED_VARIANTS = ["stage2", "no_deformation", "no_smoothness", "no_visibility", "no_pca", "segment_gate"]  # run per --stage2-seeds
STAGE2_FROM = {"stage2_ft": "stage1_ft", "stage2_oracle": "oracle"}  # Stage 2 variants started elsewhere
STAGE1_VARIANTS = {
    "stage1": {},
    # the published Im2Haircut recipe: fine-tune the prior network (AdamW 1e-4, wd 1e-3), penetration 0.3,
    # no bend term (ours)
    "stage1_ft": {"finetune_prior": True, "weights": {"penetration": 0.3, "bend": 0.0}},
}
DEFAULT_VARIANTS = ["oracle", "prior", "stage1_ft", "stage1", "stage2", "no_deformation", "no_smoothness",
                    "no_visibility", "no_pca", "segment_gate", "kf1", "kf3"]
QUICK = {"stage1": {"iterations": 30}, "stage2": {"iterations": 60, "canonical_steps": 30, "ramp_steps": 10}}

log = logging.getLogger("quality")


def prior_strands(seq: dict, prior_dir: Path, out: Path, decoding: dict) -> Path:
    """Dense strands of the prior's prediction on the reference keyframe (cached), decoded with
    Stage 1's ``length_spread`` and ``tip_scatter`` (``decoding``)."""
    from vid2haircut.fit.data import load_fit_data
    from vid2haircut.fit.outputs import dense_strands
    from vid2haircut.fit.stage1 import initial_hairmap, prior_view_input
    from vid2haircut.io.strand_formats import save_strands
    from vid2haircut.prior.model import load_prior

    path = out / "strands.npz"
    if not path.is_file():
        data = load_fit_data(seq["root"], seq["subject"], seq["keyframes"], seq["head"], seq["targets"],
                             n_keyframes=1, occlude_head=False)
        net, codec, _ = load_prior(prior_dir)
        z, mask = initial_hairmap(data, codec, (net, prior_view_input(data, net.cfg.input_size, "cpu")))
        save_strands(path, dense_strands(z, mask, data.head, codec, 10000, 0, data.head_model,
                                         **decoding))
    return path


def oracle_strands(seq: dict, prior_dir: Path, out: Path, cfg) -> Path:
    """Dense strands of the ground truth encoded into the hair map (cached): each texel holds the
    codec coefficients of its nearest ground-truth strand, decoded like Stage 2's output (``cfg``, a
    Stage 2 config: its decoding settings, and carving with its keyframes). The hair map and codec
    are written next to them (``hairmap.npz``, ``codec.npz``), so Stage 2 can start from them like
    from a Stage 1 folder."""
    from vid2haircut.fit.data import load_fit_data
    from vid2haircut.fit.outputs import stage_strands, write_hairmap
    from vid2haircut.io.strand_formats import load_strands, save_strands
    from vid2haircut.prior.hairmap import encode_strands
    from vid2haircut.prior.model import load_prior

    path = out / "strands.npz"
    if not (path.is_file() and (out / "hairmap.npz").is_file()):
        data = load_fit_data(seq["root"], seq["subject"], seq["keyframes"], seq["head"], seq["targets"],
                             size=cfg.render.size, n_keyframes=cfg.n_keyframes, occlude_head=cfg.render.occlude_head)
        _, codec, _ = load_prior(prior_dir)
        hm = encode_strands(load_strands(seq["gt"]), data.head, codec, res=32)
        save_strands(path, stage_strands(hm.z, hm.mask, data, codec, cfg)[0])
        write_hairmap(out / "hairmap.npz", hm.z, hm.mask, codec.fingerprint(), data.head_model)
        codec.save(out / "codec.npz")
    return path


def run_variant(seq: dict, name: str, work: Path, prior_dir: Path, settings: dict,
                seed: int = 0) -> tuple[Path, float]:
    """Run one variant (cached) -> (strands.npz, fit seconds); Stage 2 variants with ``seed`` != 0
    run under ``<variant>_seed<seed>`` with ``Stage2Config.seed`` set (same Stage 1 start)."""
    from vid2haircut.fit.pipeline import run_stage1, run_stage2, stage1_config, stage2_config

    out = work / "runs" / seq["subject"] / (name if seed == 0 else f"{name}_seed{seed}")
    common = (seq["root"], seq["subject"], seq["keyframes"], seq["head"], seq["targets"])
    if name == "prior":
        c1 = stage1_config(settings.get("stage1", {}))
        decoding = {"length_spread": c1.length_spread, "tip_scatter": c1.tip_scatter}
        return prior_strands(seq, prior_dir, out, decoding), 0.0
    if name == "oracle":
        return oracle_strands(seq, prior_dir, out, stage2_config(settings.get("stage2", {}))), 0.0
    rec = out / ("stage1.json" if name in STAGE1_VARIANTS else "stage2.json")
    if not rec.is_file():
        if name in STAGE1_VARIANTS:
            over = _merge(settings.get("stage1", {}), STAGE1_VARIANTS[name])
            run_stage1(*common, out, prior_dir=prior_dir, settings=over, progress=False)
        else:
            base = STAGE2_FROM.get(name, "stage1")
            s1 = work / "runs" / seq["subject"] / base
            if not (s1 / "hairmap.npz").is_file():
                run_variant(seq, base, work, prior_dir, settings)
            over = _merge(settings.get("stage2", {}), STAGE2_VARIANTS[name])
            if seed:
                over["seed"] = seed
            run_stage2(*common, s1, out, settings=over, progress=False)
    return out / "strands.npz", float(json.loads(rec.read_text())["fit_seconds"])


def job_plan(names: list[str], variants: list[str]) -> list[list[tuple[str, list[str]]]]:
    """The ``--jobs`` schedule: phases of (sequence, variants) jobs, each phase's jobs independent.

    The first phase runs per sequence what other variants start from (Stage 1, or the variant of
    :data:`STAGE2_FROM`) and the variants that are not Stage 2's; the second runs each Stage 2
    variant of each sequence on its own, a variant's row for every sequence before the next
    variant's (so a schedule stopped early leaves whole rows)."""
    stage2 = [v for v in variants if v in STAGE2_VARIANTS]
    wanted = {STAGE2_FROM.get(v, "stage1") for v in stage2} | {v for v in variants if v not in STAGE2_VARIANTS}
    first = [v for v in dict.fromkeys(DEFAULT_VARIANTS + variants) if v in wanted]
    return [p for p in ([(n, first) for n in names] if first else [],
                        [(n, [v]) for v in stage2 for n in names]) if p]


def _merge(a: dict, b: dict) -> dict:
    out = json.loads(json.dumps(a))
    for k, v in b.items():
        out[k] = _merge(out.get(k, {}), v) if isinstance(v, dict) else v
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)  # see forwarded
    p.add_argument("--work", default="results/benchmarks/quality", help="cache / work folder")
    p.add_argument("--out", default=None, help="also write the Markdown table here")
    p.add_argument("--prior-dir", default=None, help="trained prior (default: the packaged one)")
    p.add_argument("--sequences", default=None, help="comma-separated family_seed names (default: the first 4)")
    p.add_argument("--variants", default=",".join(DEFAULT_VARIANTS), help="comma-separated variants")
    p.add_argument("--settings", default=None, help='JSON {"stage1": {...}, "stage2": {...}} overrides')
    p.add_argument("--frames", type=int, default=48, help="frames per synthetic sequence")
    p.add_argument("--threads", type=int, default=None, help="torch threads (per process)")
    p.add_argument("--jobs", type=int, default=1,
                   help="run the sequences' variants as this many parallel processes of this script "
                        "(one per sequence and Stage 2 variant; with --threads 1 on a 2-core machine, 2)")
    p.add_argument("--sway-gain", type=float, default=SWAY_GAIN,
                   help="hair sway gain of the synthesised sequences (SynthConfig.sway_gain)")
    p.add_argument("--head-fill", type=float, default=HEAD_FILL,
                   help="fraction of the image height that the head fills (SynthConfig.head_fill; smaller "
                        "shows more of long hair, which runs off the bottom of the image at the default)")
    p.add_argument("--depth-context", action="store_true",
                   help="depth maps and targets that also cover the visible head (a new --work); fit with "
                        '--settings \'{"stage1": {"depth_head": true}, "stage2": {"depth_head": true}}\' to use it')
    p.add_argument("--yaw-max", type=float, default=YAW_MAX,
                   help="largest head turn of the synthesised sequences, degrees (SynthConfig.yaw_max_deg; "
                        "larger shows more of the back, which no keyframe sees at the default)")
    p.add_argument("--keyframes", type=int, default=6,
                   help="keyframes the front stages select (KeyframeConfig.num_keyframes); Stage 2 uses "
                        "Stage2Config.n_keyframes of them (set it with --settings)")
    p.add_argument("--quick", action="store_true", help="2 sequences, short schedules")
    p.add_argument("--stage2-seeds", default="0",
                   help="comma-separated Stage 2 seeds; the full method and its four switch ablations are "
                        "run once per seed and the table shows their mean (the per-seed means are listed "
                        "below it)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    import vid2haircut  # before torch, as in the CLI: see the package docstring
    import torch

    from vid2haircut.machine import machine_summary

    if args.threads:
        torch.set_num_threads(args.threads)

    prior_dir = Path(args.prior_dir) if args.prior_dir else Path(vid2haircut.__file__).parent / "data/prior/default"
    work = Path(args.work)
    settings = json.loads(args.settings) if args.settings else (QUICK if args.quick else {})
    n_kf = settings.get("stage2", {}).get("n_keyframes", 6)
    if n_kf != 6:  # the labels name the keyframe count of the full method
        for v in ("stage2", "stage2_ft", "stage2_oracle"):
            LABELS[v] = LABELS[v].replace("6 keyframes", f"{n_kf} keyframes")
    pool = {f"{f}_{s}": (f, s) for f, s in SEQUENCES}
    names = args.sequences.split(",") if args.sequences else list(pool)[: 2 if args.quick else 4]
    for name in names:
        pool.setdefault(name, parse_sequence(name))
    variants = args.variants.split(",")
    seeds = [int(x) for x in args.stage2_seeds.split(",")]
    if args.jobs > 1:
        for name in names:  # the data first, one sequence at a time; the jobs then share it
            prepare(work, *pool[name], args.frames, args.sway_gain, args.head_fill, args.keyframes, args.yaw_max,
                    args.depth_context)
        run_jobs(job_plan(names, variants), sys.argv[1:] if argv is None else argv, args.work, args.jobs,
                 __file__)
    results, times, per_seed = {}, {}, {}
    for name in names:
        t0 = time.perf_counter()
        seq = prepare(work, *pool[name], args.frames, args.sway_gain, args.head_fill, args.keyframes, args.yaw_max,
                      args.depth_context)
        log.info("%s: data ready in %.0fs", name, time.perf_counter() - t0)
        unseen = unseen_test(seq)
        for v in variants:
            ms, secs = [], []
            for sd in (seeds if v in SEEDED_VARIANTS else [0]):
                strands, sec = run_variant(seq, v, work, prior_dir, settings, sd)
                ms.append(score(strands, seq["gt"], strands.with_name("metrics.json"), unseen))
                per_seed[(name, v, sd)] = ms[-1]
                secs.append(sec)
                log.info("%s %s seed %d: CD_pts %.3e CD_angle %.4f (%.0fs)", name, v, sd, ms[-1]["chamfer_pts"],
                         ms[-1]["chamfer_angle"], sec)
            results[(name, v)] = {k: float(np.mean([m[k] for m in ms])) for k in ms[0]}
            times[(name, v)] = float(np.mean(secs))
    md = table(results, names, variants)
    timing = " | ".join(f"{v} {np.mean([times[(s, v)] for s in names]):.0f}s" for v in variants
                        if v not in ("prior", "oracle"))
    regions = region_table(results, names, variants)
    bound = "".join(f"{b}\n\n" for b in (region_bound(results, names), unseen_bound(results, names)) if b)
    text = (f"Chamfer_pts (1e-4 m^2) / Chamfer_angle (rad) per sequence, lower is better.\n\n{md}\n\n"
            f"Mean Chamfer_pts (1e-4 m^2) by head region (azimuth from the face: front < 60 deg, "
            f"side 60-120 deg, back >= 120 deg; the head turns up to {args.yaw_max:g} deg):\n\n{regions}\n\n"
            f"{bound}"
            f"Median tip height of the strands rooted in each region above the ground truth's, cm (mean over "
            f"the sequences; positive = the hair ends too high, i.e. is too short):\n\n"
            f"{tip_table(results, names, variants)}\n\n"
            f"Mean fit time per variant (this machine: {machine_summary()}): {timing}\n")
    losses = loss_table(work, names, variants)
    if losses:
        text += "\n" + losses + "\n"
    if len(seeds) > 1:
        text += "\n" + seed_table(per_seed, names, [v for v in variants if v in SEEDED_VARIANTS], seeds) + "\n"
    emit(text, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
