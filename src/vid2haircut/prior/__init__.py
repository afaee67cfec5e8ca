"""Hair prior: strand codec (whitened PCA of Fourier features), scalp hair map, training corpus.

- :mod:`.codec`: :class:`StrandCodec` (fit / encode / decode / save / load), :func:`component_mask`.
- :mod:`.hairmap`: :class:`HairMap` (z (K,H,W) channel-first, mask (H,W)), :func:`encode_strands`,
  :func:`decode_guides`, :func:`decode_texels`, :func:`decode_dense`.
- :mod:`.scalp` (texel grids, cached), :mod:`.upsample` (HAAR nearest / bilinear blend).
- :mod:`.corpus`: generated training / held-out corpora; :mod:`.roundtrip`: round-trip errors.
- :mod:`.model`: the learned prior :class:`~.model.PriorNet` (+ ``PriorConfig``, ``load_prior``);
  :mod:`.views`: ``prior_input`` (the canonical head-centred crop) and the training-view renderer;
  :mod:`.dataset`, :mod:`.losses`, :mod:`.train` (``train_prior``: the cached training stage);
  (prior vs mean hairstyle on unseen views: :mod:`vid2haircut.evaluate.prior_eval`)
"""

from vid2haircut.prior.codec import StrandCodec, component_mask
from vid2haircut.prior.hairmap import (DenseStrands, Guides, HairMap, decode_dense, decode_guides, decode_texels,
                                       encode_strands)

__all__ = ["StrandCodec", "component_mask", "HairMap", "Guides", "DenseStrands", "encode_strands",
           "decode_guides", "decode_texels", "decode_dense"]
