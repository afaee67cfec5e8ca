"""Mix two Stage 2 sweep runs' hair maps by PCA component: which components carry a setting's effect.

For every sequence, the new sweep setting ``--name`` takes the coefficients of components
0..``--split``-1 from run ``--coarse`` and those from ``--split`` on from run ``--fine`` (both
``benchmarks/stage2_sweep.py`` settings of the same work folder); its record is ``--coarse``'s,
so the dense strands are decoded and carved exactly as that run's. No fitting: score the new
settings with ``stage2_sweep.py --score-only``. Used to find where the PCA consistency's Chamfer
effects live (``benchmarks/RESULTS.md``, "PCA consistency on the fine components only"):

    python benchmarks/mix_components.py --work results/benchmarks/quality_v22 --coarse pcachg1 --fine base --split 10
    python benchmarks/stage2_sweep.py --work results/benchmarks/quality_v22 --score-only \
        --grid '{"mix_pcachg1_base_10": {}, "base": {}, "pcachg1": {}}'
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import quality_data  # noqa: E402  (the benchmark's sequence names)

from vid2haircut.fit.outputs import load_hairmap, write_hairmap  # noqa: E402


def mix(work: Path, name: str, coarse: str, fine: str, split: int, setting: str) -> Path:
    """Write sweep run ``setting`` of sequence ``name``: ``coarse``'s components < split, ``fine``'s
    from split on, ``coarse``'s record; returns its folder."""
    src_c, src_f = work / "sweep" / name / coarse, work / "sweep" / name / fine
    zc, mask, fp = load_hairmap(src_c / "hairmap.npz")
    zf, mask_f, fp_f = load_hairmap(src_f / "hairmap.npz")
    if fp != fp_f or zc.shape != zf.shape or not bool((mask == mask_f).all()):
        raise ValueError(f"{src_c} and {src_f}: hair maps of different codecs, shapes or masks")
    if not 0 < split < zc.shape[0]:
        raise ValueError(f"--split must lie in (0, {zc.shape[0]}), got {split}")
    z = zc.clone()
    z[split:] = zf[split:]
    out = work / "sweep" / name / setting
    out.mkdir(parents=True, exist_ok=True)
    with np.load(src_c / "hairmap.npz", allow_pickle=False) as d:
        head_model = str(d["head_model"]) if "head_model" in d else ""
    write_hairmap(out / "hairmap.npz", z, mask, fp, head_model)
    shutil.copy2(src_c / "stage2.json", out / "stage2.json")
    (out / "strands.npz").unlink(missing_ok=True)     # decoded again by stage2_sweep's scoring
    (out / "metrics.json").unlink(missing_ok=True)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", required=True, help="a benchmarks/quality.py work folder with stage2_sweep runs")
    p.add_argument("--coarse", required=True, help="sweep setting giving components < --split")
    p.add_argument("--fine", required=True, help="sweep setting giving components >= --split")
    p.add_argument("--split", type=int, default=10)
    p.add_argument("--name", default=None, help="new setting name (default mix_<coarse>_<fine>_<split>)")
    p.add_argument("--sequences", default=",".join(f"{f}_{s}" for f, s in quality_data.SEQUENCES))
    args = p.parse_args(argv)
    setting = args.name or f"mix_{args.coarse}_{args.fine}_{args.split}"
    for n in args.sequences.split(","):
        print(mix(Path(args.work), n, args.coarse, args.fine, args.split, setting), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
