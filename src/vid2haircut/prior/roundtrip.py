"""Round-trip errors of the strand codec and the hair map (used by tests and benchmarks)."""

from __future__ import annotations

from typing import Any, NamedTuple, Sequence

import numpy as np
import torch

from vid2haircut.prior.codec import StrandCodec
from vid2haircut.prior.corpus import Corpus
from vid2haircut.prior.hairmap import assign_texels, decode_guides, encode_strands
from vid2haircut.strands import StrandSet

__all__ = ["codec_point_error", "HairMapRoundTrip", "hairmap_roundtrip", "codec_errors_by_family",
           "hairmap_errors_by_family", "markdown_table"]


def codec_point_error(codec: StrandCodec, points: np.ndarray, k: int | None = None,
                      batch: int = 8192) -> float:
    """Mean Euclidean error of an encode -> decode round trip.

    Args:
        codec: fitted codec.
        points: (N,P,3) strands with P = ``codec.n_points``.
        k: use only the first k components (default all K).
        batch: strands per batch.

    Returns:
        Mean distance in metres over the P-1 non-root points of all strands (the root is exact).
    """
    c = codec if k is None or k == codec.k else codec.truncate(k)
    total, count = 0.0, 0
    with torch.no_grad():
        for i in range(0, len(points), batch):
            x = torch.as_tensor(np.asarray(points[i:i + batch], np.float32))
            y = c.decode(c.encode(x), x[:, 0])
            total += float((y - x)[:, 1:].norm(dim=-1).double().sum())
            count += x.shape[0] * (x.shape[1] - 1)
    return total / max(count, 1)


class HairMapRoundTrip(NamedTuple):
    """Encode -> decode guides -> compare with each texel's nearest ground-truth strand.

    Attributes:
        point_error: mean distance (m) between guide points and the matched strand's points
            (includes the root displacement from the strand's root to the texel centre).
        shape_error: mean distance (m) of the root-relative offsets (the codec part alone).
        root_error: mean distance (m) between guide roots and matched strand roots.
        n_guides: number of decoded guides (hair-bearing texels).
    """

    point_error: float
    shape_error: float
    root_error: float
    n_guides: int


def hairmap_roundtrip(strands: StrandSet, head: Any, codec: StrandCodec, res: int = 32) -> HairMapRoundTrip:
    """Hair-map round-trip error of one hairstyle (see :class:`HairMapRoundTrip`)."""
    strands = strands.resample(codec.n_points)
    hm = encode_strands(strands, head, codec, res=res)
    with torch.no_grad():
        guides = decode_guides(hm, head, codec)
    assign = assign_texels(strands, head, res)
    gt = torch.as_tensor(strands.points[assign.strand_index.ravel()[guides.texel_index.numpy()]])
    g = guides.points.float()
    if g.shape[0] == 0:
        return HairMapRoundTrip(float("nan"), float("nan"), float("nan"), 0)
    point = (g - gt)[:, 1:].norm(dim=-1).mean()
    shape = ((g[:, 1:] - g[:, :1]) - (gt[:, 1:] - gt[:, :1])).norm(dim=-1).mean()
    root = (g[:, 0] - gt[:, 0]).norm(dim=-1).mean()
    return HairMapRoundTrip(float(point), float(shape), float(root), int(g.shape[0]))


def _families(corpus: Corpus) -> list[str]:
    return list(dict.fromkeys(f for f, _ in corpus.styles))


def codec_errors_by_family(codec: StrandCodec, corpus: Corpus, ks: Sequence[int]) -> dict[str, dict[int, float]]:
    """Mean codec round-trip point error (m) per family and per number of components k."""
    return {fam: {int(k): codec_point_error(codec, corpus.points[corpus.family_index(fam)], k) for k in ks}
            for fam in _families(corpus)}


def hairmap_errors_by_family(codec: StrandCodec, corpus: Corpus, head: Any,
                             res: int = 32) -> dict[str, HairMapRoundTrip]:
    """Hair-map round trip per family, averaged over its styles (weighted by guide count)."""
    out = {}
    for fam in _families(corpus):
        rts = [hairmap_roundtrip(corpus.strand_set(i), head, codec, res)
               for i, (f, _) in enumerate(corpus.styles) if f == fam]
        n = np.array([r.n_guides for r in rts], np.float64)
        w = n / max(n.sum(), 1.0)
        mean = [float(np.nansum(w * np.array([getattr(r, name) for r in rts])))
                for name in ("point_error", "shape_error", "root_error")]
        out[fam] = HairMapRoundTrip(*mean, int(n.sum()))
    return out


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A GitHub-flavoured Markdown table (floats printed with 3 decimals)."""
    def cell(v: Any) -> str:
        return f"{v:.3f}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)
