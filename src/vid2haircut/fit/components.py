"""The parts the fitting stages' configs share (:mod:`vid2haircut.fit.config`): the loss weights, the
render settings, the method switches that make each ablation one override, and the defaults of the
dense-output decoding. One dataclass per component, a docstring under every field.
"""

from __future__ import annotations

from dataclasses import dataclass

# Choices of string settings, here (no torch) so that the workflow can check a config cheaply.
DEPTH_ALIGNMENTS = ("quantile", "affine")
"""How the depth term aligns a render's depth with the target's (:func:`vid2haircut.fit.image_terms.depth_loss`)."""
SMOOTH_DIRECTION_FORMS = ("absolute", "relative", "change")
"""What the direction smoothness penalises (:func:`vid2haircut.fit.losses.smoothness_losses`)."""
COMPOSITINGS = ("auto", "bins", "exact")
"""The renderer's compositing models (:func:`vid2haircut.render.render_strands`, ``compositing``;
"auto": "exact" on the CPU's numba kernels, "bins" on the torch ones, CUDA)."""
HIDDEN_DIRECTION_SOURCES = ("render", "target")
"""What :func:`vid2haircut.fit.scene.hidden_direction_term` aligns hidden segments with
(``Stage2Config.hidden_direction_from``)."""

# Dense-output decoding shared by both stages (vid2haircut.fit.outputs.dense_strands).
LENGTH_SPREAD = 0.04
"""Default relative spread of the dense strands' lengths (uneven ends,
:func:`vid2haircut.polylines.vary_lengths`): the robust spread of strand length within one texel of the
32x32 map over the prior's training corpus (``benchmarks/length_spread.py``)."""
CARVE_TOLERANCE = 1.0
"""Default of ``carve_tolerance`` (both stages): the dense strands are cut back where a keyframe
shows them more than this many fitting pixels outside its target silhouette, in front of the head
(:mod:`vid2haircut.fit.carve`; 0 = off). Measured on the quality benchmark (``benchmarks/RESULTS.md``,
"Silhouette carving")."""
TIP_SCATTER_MEASURED = 0.0022
"""The tip fan-out (:func:`vid2haircut.polylines.scatter_strands`) measured and not kept: the corpus's
spread across the strands' direction within one texel. Lower Chamfer_pts, higher Chamfer_angle
(``benchmarks/RESULTS.md``, "Uneven ends"), so ``tip_scatter`` defaults to 0."""


@dataclass
class LossWeights:
    """Weights of the loss terms; the trainer sums ``weight * term`` over the model's loss dict."""

    silhouette: float = 1.0
    """L1 between the rendered and the target hair silhouette (method.md: 1)."""
    direction: float = 0.8
    """Undirected L1 between rendered and target 2D hair directions (method.md: 0.8)."""
    depth: float = 0.1
    """L1 between the rendered depth, aligned to the target's relative scale, and the target inside both
    masks (Vid2Haircut: 0.1; Stage 2 defaults to 1 with its least-squares alignment)."""
    hidden_direction: float = 0.0
    """Stage 2 with visibility masking: the segments a keyframe does not show (so the gate keeps that
    keyframe's image terms from them) run along the direction of the hair covering them, by default
    the rendered direction of the fitted hair drawn over them
    (:attr:`vid2haircut.fit.config.Stage2Config.hidden_direction_from`,
    :func:`vid2haircut.fit.image_terms.hidden_direction_loss`; not published). Stage 2 uses 0.1."""
    outside: float = 0.0
    """Strand points a keyframe shows outside its target silhouette pay their distance to it, in
    fitting pixels beyond ``outside_tolerance`` (:func:`vid2haircut.fit.image_terms.outside_loss`; not
    published)."""
    penetration: float = 1.0e4
    """mean(relu(-sdf)) of the strand points, metres (Vid2Haircut: 1e4)."""
    smooth_length: float = 1.0
    """Neighbour-strand smoothness of strand length, |Laplacian of length| in metres (method.md: 1)."""
    smooth_length_back: float = 1.0
    """Length smoothness weight in the back region (method.md: 100; measured on generated sequences,
    100 pulls layered cuts such as a bob far from the truth, so the back is not weighted up)."""
    smooth_direction: float = 0.3
    """Neighbour-strand smoothness of directions, mean (1 - cos) of nearby segments (method.md: 1;
    0.3 measured better: at 1 it trades Chamfer_pts for Chamfer_angle). Stage 2 uses 3 with its
    "relative" form (:attr:`vid2haircut.fit.config.Stage2Config.smooth_direction_form`)."""
    smooth_tip: float = 0.0
    """Neighbour-strand smoothness of the tip height, |Laplacian of the tip's y| in metres
    (:func:`vid2haircut.fit.losses.tip_height_loss`; not published). Off: measured on
    ``benchmarks/quality.py`` (Stage 2 seed 0, Chamfer_pts 1e-4 m^2), weight 1 moved the tips little
    and changed bob 0.077 -> 0.093, bangs 0.196 -> 0.203; weight 10 made the wavy sequence 0.585 ->
    0.829: the tips are pulled towards the too-short front strands as much as the reverse."""
    pca: float = 1.0
    """PCA-coefficient consistency of unobserved texels with their neighbours (not published; 1)."""
    anchor: float = 1.0e3
    """Stage 2: guide points that no keyframe shows stay near their Stage 1 positions: mean |x - x_start|^2
    over those points, m^2 (:func:`vid2haircut.fit.losses.anchor_loss`; not published). The image
    terms reach only visible points, so without it the hidden parts of a strand (under the outer
    layer, at the back) move only as a side effect of the visible parts and of the smoothness: the
    direction smoothness, with nothing to oppose it, reshaped the unseen back of a bob (back-region
    Chamfer_pts 0.026 -> 0.047, 1e-4 m^2) and short side hair stood off the head. Measured with
    ``benchmarks/stage2_sweep.py`` (seed 0, bob / short / side-parted / wavy, mean Chamfer_pts):
    0 gives 0.130, 100 gives 0.126, 1000 gives 0.104, 10000 gives 0.112 (Stage 1: 0.127)."""
    bend: float = 10.0
    """Strands bend no tighter than ``min_bend_radius`` (:func:`vid2haircut.fit.losses.bend_loss`, on
    the full-resolution guides, both stages; not published). The images at the fitting resolution
    cannot see millimetre kinks, and the prior decodes short strands with them: on the short style
    the Stage 2 strands turned 14 degrees per segment (100 points; the ground truth 0.7) and 76% of
    their segments bent tighter than 3 mm (ground truth 0.1%). Measured with
    ``benchmarks/stage2_sweep.py`` (Stage 2 only, seed 0, bob / short / side-parted / wavy / bangs,
    mean Chamfer_pts 1e-4 m^2 / Chamfer_angle rad): off 0.114 / 0.293; weight 1 0.113 / 0.273;
    weight 10 0.113 / 0.266 (short 0.529 -> 0.406 rad, bangs 0.154 -> 0.147 in Chamfer_pts);
    weight 10 with a 10 mm radius 0.115 / 0.265; weight 100 with 5 mm 0.170 (short and bangs
    collapse)."""
    gravity: float = 0.0
    """Stage 2: rising guide segments pay their climb, mean relu(u . up) over segments
    (:func:`vid2haircut.fit.losses.gravity_loss`; method.md lists gravity 0.1 without a definition).
    Off: measured with ``benchmarks/stage2_sweep.py`` (first quality draw, seed 0, short and bangs
    styles, the two whose fits climb: the term is 0.043 and 0.013 on their Stage 2 dense strands,
    0.009 and 0.002 on the ground truth), Chamfer_pts 1e-4 m^2 0.0342 / 0.0455 off, 0.0350 / 0.0469 at 0.1,
    0.0351 / 0.0476 at 1; Chamfer_angle a little lower (0.3856 / 0.1816 at 0.1 against 0.3881 / 0.1832)."""
    canonical: float = 1.0e4
    """Offsets of the reference (canonical) keyframe pushed to zero, mean |dx|^2 in m^2 (method.md: 1e4)."""
    motion: float = 1.0e-6
    """Mean squared per-frame offset |dx_t|^2, m^2 (method.md: 1e-6)."""
    frame_code: float = 1.0e-6
    """Mean squared frame latent code (method.md: 1e-6)."""


@dataclass
class RenderSettings:
    """How guide strands are drawn while fitting (a cheap stand-in for the dense hair)."""

    size: int = 160
    """Fitting resolution: the longer image side in pixels (targets are downsampled to it)."""
    n_points: int = 32
    """Points per guide strand when rendered (subsampled from the codec's 100)."""
    strand_width: float = 0.004
    """Short-axis size of each guide Gaussian, metres: a guide stands for the strands of its texel
    (about 6.5 mm apart on a 32x32 map), so it is drawn much wider than one hair (0.35 mm)."""
    silhouette_opacity: float = 0.3
    """Peak opacity of the guide Gaussians in the silhouette term (below 1: the silhouette of the guides
    drawn at this opacity; direction, depth and visibility come from the opaque render;
    ``render_strands(silhouette_opacity=...)``, one window walk for both in the numba backend).
    A guide stands for ~20 hairs and is drawn 4 mm wide, so one opaque guide covers its pixels
    fully and the silhouette is met wherever a single guide passes: it cannot tell where most of
    the hair ends. At 0.3 a pixel
    is covered only where several guides overlap, as where many hairs do, and thins where few
    remain, as the target masks do at the ends. Measured on the quality benchmark's first draw
    (seed 0, exact Chamfer_pts 1e-4 m^2): opaque, Stage 1 0.0999 and Stage 2 0.0642; at 0.3,
    0.0937 and 0.0589 (shoulder-length 0.078 -> 0.061, bangs 0.092 -> 0.080, wavy 0.090 -> 0.093).
    Translucent guides in every channel instead (0.3) give Stage 2 0.0655 (wavy 0.144): direction
    and depth composited through several translucent layers mix those layers. As a second render it
    cost ~30% of a guide step; from the opaque render's walk, 98.5 ms forward+backward against
    145.4 ms for two renders (6 keyframes of 442 guides at 160 px, 2 threads)."""
    occlude_head: bool = True
    """Hide hair behind the head mesh (rendered once per keyframe)."""
    bins: int = 16
    """Depth-compositing bins of the renderer."""
    depth_bin: float = 0.002
    """Depth-bin size of the renderer, metres."""
    compositing: str = "bins"
    """The renderer's compositing model: "bins" (depth-binned, the default: CPU and CUDA), "exact"
    (front to back in depth order, each pixel stopping once its transmittance falls below
    ``t_min``; CPU only, numba backend; the renderer's own default there) or "auto" ("exact" on the
    CPU, "bins" on CUDA). The fits keep the bins because they fit better with them, in the same
    time: with "exact" (Stage 2 with ``gate_bins_every`` 5) the quality benchmark's Stage 2 gave
    Chamfer_pts 0.0347 and 0.0353 (first draw, seeds 0 and 1) and 0.0331 (second draw) against the
    bins' 0.0344, 0.0349 and 0.0323, and Stage 1 0.0738 against 0.0731 (1e-4 m^2;
    ``benchmarks/RESULTS.md``, "Exact compositing in the fits: both draws and a second seed")."""
    t_min: float = 1e-4
    """Transmittance at which a pixel stops compositing with ``compositing: exact``."""
    vis_weight: float = 0.3
    """A guide segment counts as visible in a keyframe when its compositing weight reaches this at
    some pixel (drives the visibility-aware updates and the observed-texel test). Measured with
    ``benchmarks/stage2_sweep.py`` (first quality draw, seed 0, exact Chamfer_pts 1e-4 m^2): 0.1 gives
    0.0736, 0.2 0.0656, 0.3 0.0642, 0.4 0.0663, 0.5 0.0682; looser tests help only the short style."""


@dataclass
class Switches:
    """Method components that can be turned off (ablations are one override)."""

    use_deformation: bool = True
    """Stage 2: per-frame deformation MLP (False: rigid head pose only; offsets exactly zero)."""
    use_smoothness: bool = True
    """Stage 2: neighbour-strand smoothness of length and direction."""
    use_visibility: bool = True
    """Stage 2: the gradient of keyframe t reaches only the canonical segments visible in t."""
    use_pca_consistency: bool = True
    """Stage 2: PCA-coefficient consistency between observed and unobserved scalp texels."""
