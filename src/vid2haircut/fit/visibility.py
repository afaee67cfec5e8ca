"""Visibility-aware updates: the gradient of keyframe t reaches only the canonical segments visible in t.

All keyframes are rendered in one batch from per-frame copies of the canonical points. A
:class:`VisibilityGate` sits between the canonical points and their per-frame copies: it is the
identity in the forward pass, and in the backward pass multiplies the gradient of each frame's
copy by that frame's visibility of every point. The visibility is the renderer's per-segment
visibility of the *same* forward pass (set with :meth:`VisibilityGate.set_visibility` after the
render, read during backward), so the mask is never a step late. A point counts as visible in a
frame when one of its two adjacent segments is.

With ``Stage2Config.visibility_unit`` "strand" the gate keeps every point of a strand that has a
visible segment in the frame (:func:`gate_visibility`).

Only the image terms pass through the gate; geometry terms (penetration, smoothness, PCA
consistency) act on the un-gated canonical points, so invisible segments move only through them
and the codec prior.

Example::

    gate = VisibilityGate()
    per_frame = gate(canonical[None].expand(B, -1, -1, -1))      # (B,N,P,3), identity forward
    out = render_strands(deform(per_frame), ...)
    gate.set_visibility(out.visibility)                           # (B,N,P-1) bool
    loss(out).backward()          # canonical.grad = sum_t vis_t * dL_t/dx_t
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["VISIBILITY_UNITS", "VisibilityGate", "check_visibility_unit", "gate_visibility", "point_visibility",
           "texel_visible_fraction"]

VISIBILITY_UNITS = ("segment", "strand")
"""Values of ``Stage2Config.visibility_unit`` (see :func:`gate_visibility`)."""


def point_visibility(segment_visible: Tensor) -> Tensor:
    """(...,N,P-1) bool segment visibility -> (...,N,P) bool point visibility (either adjacent segment)."""
    v = segment_visible.bool()
    pad = torch.zeros_like(v[..., :1])
    return torch.cat([v, pad], -1) | torch.cat([pad, v], -1)


def gate_visibility(segment_visible: Tensor, unit: str = "segment") -> Tensor:
    """(B,N,P-1) bool per-segment visibility -> the (B,N,P-1) bool visibility the gate uses.

    ``unit`` "segment": as rendered (the gradient of frame t reaches the segments visible in t);
    "strand": every segment of a strand that shows a visible segment in t (frame t updates the
    strands it sees, and a strand hidden in t gets nothing from t).
    """
    check_visibility_unit(unit)
    if unit == "strand":
        return segment_visible.any(-1, keepdim=True).expand_as(segment_visible)
    return segment_visible


def check_visibility_unit(unit: str) -> None:
    """ValueError unless ``unit`` is one of :data:`VISIBILITY_UNITS`."""
    if unit not in VISIBILITY_UNITS:
        raise ValueError(f"unknown visibility_unit {unit!r} (expected one of {', '.join(VISIBILITY_UNITS)})")


def texel_visible_fraction(segment_visible: Tensor) -> Tensor:
    """(B,N,P-1) bool -> (B,N) float fraction of each strand's segments visible in each frame."""
    return segment_visible.float().mean(-1)


class _Gate(torch.autograd.Function):
    @staticmethod
    def forward(ctx, points: Tensor, gate: "VisibilityGate") -> Tensor:  # noqa: D401
        ctx.gate = gate
        return points.view_as(points)

    @staticmethod
    def backward(ctx, grad: Tensor):
        mask = ctx.gate.mask
        if mask is None:
            raise RuntimeError("VisibilityGate: set_visibility() was not called before backward")
        if mask.shape != grad.shape[:-1]:
            raise RuntimeError(f"VisibilityGate: visibility {tuple(mask.shape)} does not match the gated points "
                               f"{tuple(grad.shape)}")
        return grad * mask[..., None].to(grad.dtype), None


class VisibilityGate:
    """Identity on per-frame points whose backward keeps only the gradient of visible points.

    Attributes:
        mask: (B,N,P) bool point visibility of the last :meth:`set_visibility` call, or None.
        enabled: False makes the gate a plain identity (ablation "without visibility").
    """

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = bool(enabled)
        self.mask: Tensor | None = None

    def __call__(self, points: Tensor) -> Tensor:
        """points: (B,N,P,3) per-frame copies of the canonical points -> the same values, gated."""
        self.mask = None
        return _Gate.apply(points, self) if self.enabled else points

    def set_visibility(self, segment_visible: Tensor) -> None:
        """Record the (B,N,P-1) bool per-segment visibility of the frames just rendered."""
        self.mask = point_visibility(segment_visible.detach())
