"""Hair prior: strand codec (whitened PCA of Fourier features), scalp hair map, training corpus."""

from vid2haircut.prior.codec import StrandCodec, component_mask

__all__ = ["StrandCodec", "component_mask"]
