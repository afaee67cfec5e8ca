"""Strand codec and hair-map round trip on held-out generated hairstyles, as Markdown tables.

Fits the codec on the training seeds of every generator family and reports, on held-out seeds,
the mean point error for K = 16, 32, 64 per family and the hair-map round trip (encode -> decode
guides -> compare with each texel's nearest ground-truth strand) per family.

    .venv/bin/python benchmarks/codec_roundtrip.py --out results/benchmarks/codec_roundtrip.md

Generated corpora are cached (``--cache``), so a second run only refits and evaluates.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

from vid2haircut.head import get_head
from vid2haircut.io.atomic import write_json, write_text
from vid2haircut.prior.corpus import CorpusConfig, build_corpus, fit_codec, load_corpus, save_corpus
from vid2haircut.prior.roundtrip import codec_errors_by_family, hairmap_errors_by_family, markdown_table


def corpus_cached(cache: Path | None, name: str, families, seeds, n_strands, head):
    """Build a corpus or read it from ``cache/name.npz`` when its recipe matches."""
    key = f"{name}_{'-'.join(families)}_{'-'.join(map(str, seeds))}_{n_strands}".replace("/", "_")
    digest = hashlib.sha256(key.encode()).hexdigest()[:12]
    path = None if cache is None else cache / f"{name}_{digest}.npz"
    recipe = None if cache is None else path.with_suffix(".json")
    if path is not None and path.is_file() and recipe.is_file() and json.loads(recipe.read_text()) == key:
        return load_corpus(path)
    corpus = build_corpus(families, seeds, n_strands, head=head)
    if path is not None:
        save_corpus(path, corpus)
        write_json(recipe, key)
    return corpus


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train-seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--test-seeds", type=int, nargs="+", default=[1000, 1001])
    ap.add_argument("--families", nargs="+", default=None)
    ap.add_argument("--strands", type=int, default=2000, help="strands per hairstyle")
    ap.add_argument("--ks", type=int, nargs="+", default=[16, 32, 64])
    ap.add_argument("--res", type=int, nargs="+", default=[32], help="hair-map resolutions")
    ap.add_argument("--cache", type=Path, default=Path("results/benchmarks/codec_corpus"))
    ap.add_argument("--out", type=Path, default=None, help="write the Markdown report here")
    args = ap.parse_args()

    cfg = CorpusConfig(tuple(args.families) if args.families else None, tuple(args.train_seeds),
                       tuple(args.test_seeds), args.strands)
    fams = cfg.families_or_all()
    head = get_head(cfg.head)
    t0 = time.perf_counter()
    train = corpus_cached(args.cache, "train", fams, cfg.train_seeds, cfg.strands_per_style, head)
    test = corpus_cached(args.cache, "test", fams, cfg.test_seeds, cfg.strands_per_style, head)
    t_corpus = time.perf_counter() - t0
    t0 = time.perf_counter()
    codec = fit_codec(train, k=max(args.ks), meta={"config": cfg.to_dict()})
    t_fit = time.perf_counter() - t0

    errs = codec_errors_by_family(codec, test, args.ks)
    rows = [[fam] + [1e3 * errs[fam][k] for k in args.ks] for fam in fams]
    rows.append(["**mean**"] + [1e3 * sum(errs[f][k] for f in fams) / len(fams) for k in args.ks])
    parts = [f"# Strand codec round trip (held-out seeds {list(cfg.test_seeds)})", "",
             f"Codec fitted on {train.n_strands} strands ({len(train.styles)} styles: seeds "
             f"{list(cfg.train_seeds)} x {len(fams)} families) in {t_fit:.1f} s; corpora built / "
             f"loaded in {t_corpus:.0f} s. Mean point error over the 99 non-root points, mm.", "",
             markdown_table(["family"] + [f"K={k}" for k in args.ks], rows), ""]
    for res in args.res:
        hm = hairmap_errors_by_family(codec, test, head, res)
        rows = [[fam, 1e3 * r.point_error, 1e3 * r.shape_error, 1e3 * r.root_error, r.n_guides]
                for fam, r in hm.items()]
        parts += [f"## Hair-map round trip, {res}x{res}, K={codec.k}", "",
                  "Encode -> decode guides -> compare with each texel's nearest ground-truth strand "
                  "(mm): all points; root-relative shape only; root displacement to the texel centre.",
                  "", markdown_table(["family", "point", "shape", "root", "guides"], rows), ""]
    report = "\n".join(parts)
    print(report)
    if args.out is not None:
        write_text(args.out, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
