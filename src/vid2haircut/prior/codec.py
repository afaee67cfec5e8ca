"""Strand codec: whitened PCA of the real FFT of root-relative strand offsets (Perm / Im2Haircut).

A strand of ``P`` points (default 100, root first) is turned into a feature vector by

1. dropping the root and taking the ``P-1`` root-relative offsets ``x_i - x_0`` (canonical head
   frame, no per-root frame),
2. a real FFT along the strand (``torch.fft.rfft(..., norm="ortho")``), giving ``P//2 + 1``
   complex xyz coefficients,
3. concatenating the real parts and the imaginary parts that are not identically zero (the DC
   term and, for an even offset count, the Nyquist term are real), so that the feature vector
   has exactly ``3 * (P-1)`` entries. The bins that stand for a conjugate pair (all but DC and
   Nyquist) are multiplied by sqrt(2), which makes the map offsets -> features exactly
   orthonormal (Parseval), so the PCA minimises the plain squared point error,
4. a whitened PCA: ``c = ((f - mean) @ basis.T) / scales`` with ``scales`` the per-component
   standard deviations over the fitting corpus, so the coefficients have ~unit variance.

Decoding inverts every step: ``f = mean + (c * scales) @ basis``, inverse real FFT, prepend the
root. Encode and decode are linear (affine), batched over any leading dims, differentiable and run
on the device / dtype of their input. With ``K = 3 * (P-1)`` (full rank) the round trip is exact
up to float rounding.

Example::

    codec = StrandCodec.fit(points, k=64)          # points (N,100,3)
    c = codec.encode(torch.as_tensor(points))      # (N,64)
    x = codec.decode(c, torch.as_tensor(points[:, 0]))  # (N,100,3)
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import torch

from vid2haircut.checks import as_whole
from vid2haircut.io.atomic import write_npz

__all__ = ["StrandCodec", "component_mask", "strand_features", "features_to_offsets"]

CODEC_FORMAT = "vid2haircut-strand-codec-v1"


def _pair_weight(n_offsets: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(n_bins,1) weights: 1 for DC (and Nyquist when n is even), sqrt(2) for the paired bins."""
    n_bins = n_offsets // 2 + 1
    w = torch.full((n_bins, 1), 2.0 ** 0.5, dtype=dtype, device=device)
    w[0] = 1.0
    if n_offsets % 2 == 0:
        w[-1] = 1.0
    return w


def _imag_keep(n_offsets: int) -> slice:
    """Slice of the rfft bins whose imaginary part is not identically zero (drop DC / Nyquist)."""
    n_bins = n_offsets // 2 + 1
    stop = n_bins - 1 if n_offsets % 2 == 0 else n_bins
    return slice(1, stop)


def strand_features(points: torch.Tensor) -> torch.Tensor:
    """Orthonormal Fourier features of root-relative offsets.

    Args:
        points: (...,P,3) strands, root first.

    Returns:
        (...,3*(P-1)) features: the real parts of all ``(P-1)//2 + 1`` rfft bins (flattened
        bin-major, xyz-minor), then the imaginary parts of the bins where they are not
        identically zero. An orthonormal linear map of the offsets.
    """
    offsets = points[..., 1:, :] - points[..., :1, :]                   # (...,P-1,3)
    n = offsets.shape[-2]
    if offsets.numel() == 0:  # MKL rejects empty FFT batches
        return offsets.new_zeros(*offsets.shape[:-2], 3 * n)
    spec = torch.fft.rfft(offsets, dim=-2, norm="ortho")                 # (...,n//2+1,3)
    w = _pair_weight(n, offsets.dtype, offsets.device)
    re = (spec.real * w).flatten(-2)
    im = (spec.imag * w)[..., _imag_keep(n), :].flatten(-2)
    return torch.cat([re, im], dim=-1)


def features_to_offsets(features: torch.Tensor, n_points: int) -> torch.Tensor:
    """Inverse of :func:`strand_features` without the root.

    Args:
        features: (...,3*(n_points-1)).
        n_points: points per strand P (root included).

    Returns:
        (...,P-1,3) root-relative offsets.
    """
    n = n_points - 1
    if features.numel() == 0:  # MKL rejects empty FFT batches
        return features.new_zeros(*features.shape[:-1], n, 3)
    n_bins = n // 2 + 1
    keep = _imag_keep(n)
    n_im = keep.stop - keep.start
    lead = features.shape[:-1]
    re = features[..., : 3 * n_bins].reshape(*lead, n_bins, 3)
    im_part = features[..., 3 * n_bins: 3 * (n_bins + n_im)].reshape(*lead, n_im, 3)
    zeros = re.new_zeros(*lead, 1, 3)
    parts = [zeros, im_part] + ([zeros] if n % 2 == 0 else [])
    im = torch.cat(parts, dim=-2)
    w = _pair_weight(n, features.dtype, features.device)
    re, im = re / w, im / w
    return torch.fft.irfft(torch.complex(re, im), n=n, dim=-2, norm="ortho")


def component_mask(k_active: int, k_total: int, device: torch.device | str | None = None,
                   dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Coarse-to-fine mask keeping the first ``k_active`` PCA components.

    Returns:
        (k_total,) tensor: 1 for components ``< k_active``, 0 after. Multiply coefficients (or
        their gradients) by it to optimise only the coarse components.
    """
    if not 0 <= k_active <= k_total:
        raise ValueError(f"component_mask: need 0 <= k_active <= k_total, got {k_active}, {k_total}")
    mask = torch.zeros(k_total, device=device, dtype=dtype)
    mask[:k_active] = 1.0
    return mask


class StrandCodec:
    """Whitened PCA of strand Fourier features.

    Attributes:
        mean: (D,) float32 mean feature vector, D = 3*(n_points-1).
        basis: (K,D) float32 orthonormal rows (principal directions, by decreasing variance).
        scales: (K,) float32 standard deviation of each component over the fitting corpus.
        n_points: points per strand P (root included).
    """

    def __init__(self, mean: torch.Tensor, basis: torch.Tensor, scales: torch.Tensor,
                 n_points: int = 100, meta: dict | None = None) -> None:
        mean, basis, scales = (torch.as_tensor(t, dtype=torch.float32) for t in (mean, basis, scales))
        d = 3 * (int(n_points) - 1)
        if mean.shape != (d,) or basis.ndim != 2 or basis.shape[1] != d or scales.shape != (basis.shape[0],):
            raise ValueError(f"StrandCodec: inconsistent shapes mean {tuple(mean.shape)}, basis "
                             f"{tuple(basis.shape)}, scales {tuple(scales.shape)} for n_points={n_points}")
        if not bool((scales > 0).all()):
            raise ValueError("StrandCodec: scales must be positive")
        self.mean, self.basis, self.scales = mean, basis, scales
        self.n_points = int(n_points)
        self.meta = dict(meta or {})

    # -- properties ------------------------------------------------------------------------
    @property
    def k(self) -> int:
        """Number of PCA components K."""
        return int(self.basis.shape[0])

    @property
    def full_rank(self) -> int:
        """Feature dimension D = 3*(P-1), the largest possible K."""
        return int(self.basis.shape[1])

    def fingerprint(self) -> str:
        """16 hex digits of a SHA-256 over the parameters (identifies a fitted codec)."""
        h = hashlib.sha256()
        h.update(f"{CODEC_FORMAT}:{self.n_points}:{self.k}".encode())
        for t in (self.mean, self.basis, self.scales):
            h.update(np.ascontiguousarray(t.detach().cpu().numpy(), dtype="<f4").tobytes())
        return h.hexdigest()[:16]

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> "StrandCodec":
        """A codec with its tensors on ``device`` / in ``dtype`` (encode/decode also follow inputs)."""
        out = StrandCodec.__new__(StrandCodec)
        out.mean, out.basis, out.scales = (t.to(device=device, dtype=dtype) for t in
                                           (self.mean, self.basis, self.scales))
        out.n_points, out.meta = self.n_points, dict(self.meta)
        return out

    def truncate(self, k: int) -> "StrandCodec":
        """A codec keeping only the first ``k`` components."""
        kk = as_whole(k)
        if kk is None or not 1 <= kk <= self.k:
            raise ValueError(f"StrandCodec.truncate: k must be a whole number in [1, {self.k}], got {k!r}")
        k = kk
        return StrandCodec(self.mean, self.basis[:k], self.scales[:k], self.n_points, self.meta)

    # -- fitting ---------------------------------------------------------------------------
    @staticmethod
    def fit(strands: np.ndarray | torch.Tensor, k: int = 64, meta: dict | None = None,
            min_scale: float = 1e-9) -> "StrandCodec":
        """Fit the whitened PCA on a corpus.

        Args:
            strands: (N,P,3) strands, root first, already resampled to P points (N >= 2).
            k: number of components, 1 <= k <= 3*(P-1).
            meta: free-form JSON-able record kept with the codec (corpus description, ...).
            min_scale: floor on the component standard deviations (metres) so that degenerate
                directions of a small corpus stay invertible.

        Returns:
            The fitted codec (float32, on the CPU). Computed in float64 from the eigen-decomposition
            of the feature covariance (the same directions and ``singular value / sqrt(N-1)``
            scales as an SVD of the centred features, at a fraction of the cost for large N).
        """
        x = torch.as_tensor(np.asarray(strands) if not torch.is_tensor(strands) else strands)
        x = x.detach().to("cpu", torch.float64)
        if x.ndim != 3 or x.shape[2] != 3 or x.shape[1] < 2:
            raise ValueError(f"StrandCodec.fit: strands must be (N,P,3), got {tuple(x.shape)}")
        if x.shape[0] < 2:
            raise ValueError(f"StrandCodec.fit: need at least 2 strands, got {x.shape[0]}")
        if not bool(torch.isfinite(x).all()):
            raise ValueError("StrandCodec.fit: strands contain NaN or infinite values")
        n, p = x.shape[:2]
        d = 3 * (p - 1)
        kk = as_whole(k)
        if kk is None or not 1 <= kk <= d:
            raise ValueError(f"StrandCodec.fit: k must be a whole number in [1, {d}] for P={p}, got {k!r}")
        k = kk
        f = strand_features(x)                                           # (N,D)
        mean = f.mean(0)
        cov = (f - mean).T @ (f - mean) / max(n - 1, 1)                  # (D,D)
        evals, evecs = torch.linalg.eigh(cov)                            # ascending
        order = torch.argsort(evals, descending=True)[:k]
        basis = evecs[:, order].T.contiguous()                           # (K,D)
        # deterministic sign: the largest-magnitude entry of each direction is positive
        idx = basis.abs().argmax(1)
        basis = basis * torch.sign(basis[torch.arange(k), idx])[:, None]
        scales = evals[order].clamp_min(0).sqrt().clamp_min(min_scale)
        info = {"n_strands": int(n), "explained_variance": float(evals[order].clamp_min(0).sum()
                                                                  / evals.clamp_min(0).sum().clamp_min(1e-30))}
        return StrandCodec(mean.float(), basis.float(), scales.float(), p, {**info, **(meta or {})})

    # -- encode / decode -------------------------------------------------------------------
    def encode(self, points: torch.Tensor) -> torch.Tensor:
        """Strands to whitened coefficients.

        Args:
            points: (...,P,3) strands, root first, P = ``n_points`` (resample first).

        Returns:
            (...,K) coefficients on the device / dtype of ``points``.
        """
        points = torch.as_tensor(points)
        if points.shape[-2:] != (self.n_points, 3):
            raise ValueError(f"StrandCodec.encode: expected (...,{self.n_points},3) strands, got "
                             f"{tuple(points.shape)}; resample to {self.n_points} points first")
        if points.dtype not in (torch.float32, torch.float64):  # integers, float16 (no FFT), bfloat16
            points = points.float()
        mean, basis, scales = (t.to(points) for t in (self.mean, self.basis, self.scales))
        f = strand_features(points)
        return ((f - mean) @ basis.T) / scales

    def decode_offsets(self, coeffs: torch.Tensor) -> torch.Tensor:
        """Coefficients to root-relative offsets of the P-1 non-root points.

        Args:
            coeffs: (...,k) with k <= K (missing trailing components count as zero).

        Returns:
            (...,P-1,3) offsets.
        """
        coeffs = torch.as_tensor(coeffs)
        k = coeffs.shape[-1]
        if k > self.k:
            raise ValueError(f"StrandCodec.decode: got {k} coefficients, codec has K={self.k}")
        if not coeffs.is_floating_point():
            coeffs = coeffs.float()
        mean, basis, scales = (t.to(coeffs) for t in (self.mean, self.basis[:k], self.scales[:k]))
        f = mean + (coeffs * scales) @ basis
        return features_to_offsets(f, self.n_points)

    def decode(self, coeffs: torch.Tensor, roots: torch.Tensor) -> torch.Tensor:
        """Coefficients and roots to strands.

        Args:
            coeffs: (...,k), k <= K.
            roots: (...,3) root points (broadcast against ``coeffs``' leading dims).

        Returns:
            (...,P,3) strands, root first.
        """
        offsets = self.decode_offsets(coeffs)                            # (...,P-1,3)
        roots = torch.as_tensor(roots).to(offsets)
        lead = torch.broadcast_shapes(offsets.shape[:-2], roots.shape[:-1])
        roots = roots.expand(*lead, 3)[..., None, :]
        offsets = offsets.expand(*lead, *offsets.shape[-2:])
        return torch.cat([roots, roots + offsets], dim=-2)

    # -- persistence -----------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Atomically write the codec to an ``.npz`` (with K, P, fingerprint and meta JSON)."""
        write_npz(path, compressed=False, format=np.array(CODEC_FORMAT),
                  mean=self.mean.detach().cpu().numpy(), basis=self.basis.detach().cpu().numpy(),
                  scales=self.scales.detach().cpu().numpy(), k=np.int64(self.k),
                  n_points=np.int64(self.n_points), fingerprint=np.array(self.fingerprint()),
                  meta=np.array(json.dumps(self.meta, sort_keys=True, default=str)))

    @staticmethod
    def load(path: str | Path) -> "StrandCodec":
        """Read a codec written by :meth:`save`; checks its format, shapes and fingerprint."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: strand codec file not found")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {key: z[key] for key in z.files}
        except Exception as exc:  # noqa: BLE001 - report any decoding failure with the file name
            raise ValueError(f"{path}: not a readable .npz strand codec ({exc})") from exc
        missing = {"format", "mean", "basis", "scales", "k", "n_points", "fingerprint"} - set(data)
        if missing:
            raise ValueError(f"{path}: strand codec misses entries {sorted(missing)}")
        if str(data["format"]) != CODEC_FORMAT:
            raise ValueError(f"{path}: unknown codec format {str(data['format'])!r}, expected {CODEC_FORMAT!r}")
        meta = json.loads(str(data["meta"])) if "meta" in data else {}
        codec = StrandCodec(torch.from_numpy(data["mean"]), torch.from_numpy(data["basis"]),
                            torch.from_numpy(data["scales"]), int(data["n_points"]), meta)
        if codec.k != int(data["k"]):
            raise ValueError(f"{path}: stored K={int(data['k'])} but basis has {codec.k} rows")
        if codec.fingerprint() != str(data["fingerprint"]):
            raise ValueError(f"{path}: fingerprint mismatch (file corrupted or edited)")
        return codec

    def __repr__(self) -> str:
        return f"StrandCodec(K={self.k}, n_points={self.n_points}, fingerprint={self.fingerprint()})"
