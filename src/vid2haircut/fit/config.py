"""Configuration of the fitting stages (nerfstudio style: one dataclass per component, a docstring
under every field): :class:`Stage1Config` and :class:`Stage2Config`, built from the shared parts in
:mod:`vid2haircut.fit.components`.

Loss weights default to the published Vid2Haircut values (``shared/docs/method.md``) where our losses
have the same units; the rest are tuned on ``benchmarks/quality.py`` and say so. Every setting can
be overridden from a JSON object (``--settings``) with :func:`vid2haircut.fit.settings.apply_overrides`, e.g.
``{"switches": {"use_deformation": false}}`` or the dotted form ``{"switches.use_deformation": false}``,
so each ablation is one override.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from vid2haircut.fit.components import CARVE_TOLERANCE, LENGTH_SPREAD, LossWeights, RenderSettings, Switches


@dataclass
class Stage1Config:
    """Stage 1: single-view fit of the hair map on the reference keyframe (Im2Haircut baseline)."""

    iterations: int = 100
    """Optimisation steps (method.md: 100)."""
    coarse_steps: int = 20
    """Steps during which only the first ``coarse_components`` PCA components are optimised."""
    coarse_components: int = 10
    """PCA components optimised during the coarse steps (method.md: 10)."""
    finetune_prior: bool = False
    """With a prior: True fine-tunes its weights (Im2Haircut's recipe); False (default, measured better,
    see :mod:`vid2haircut.fit.stage1`) optimises Z starting from its prediction."""
    lr_prior: float = 1.0e-4
    """AdamW learning rate when fine-tuning the prior network (method.md: 1e-4)."""
    weight_decay_prior: float = 1.0e-3
    """AdamW weight decay when fine-tuning the prior network (method.md: 1e-3)."""
    lr_z: float = 0.03
    """Learning rate when the hair map Z itself is the parameter (whitened units, first component)."""
    lr_gain_power: float = 0.5
    """Per-component step size (s_k / s_0) ** power of Z (see :class:`vid2haircut.fit.scene.ZMap`)."""
    z_optimizer: str = "shared_adam"
    """Optimiser of Z: "shared_adam" (:mod:`vid2haircut.fit.optim`) or "adam"."""
    length_step_ref: float = 0.15
    """Strands shorter than this (metres, at the start) take proportionally smaller Z steps
    (:func:`vid2haircut.fit.scene.length_step_gain`; 0 = off): a whitened step moves a 4 cm strand
    as many millimetres as a 40 cm one. Measured on ``benchmarks/quality.py`` (6 sequences): 0.15
    lowers Stage 1's Chamfer_pts on the short hairstyle from 0.136 to 0.076 and on the bangs from
    0.294 to 0.234 (1e-4 m^2), long hair is unchanged."""
    penetration_margin: float = 0.001
    """Depth (metres) inside the fitted head surface that the penetration term tolerates
    (:func:`vid2haircut.fit.losses.penetration_loss`; 0 = none). The fitted head's pose is off by
    0.6-2.5 mm, so hair lying on the true scalp can sit slightly inside it. Measured on
    ``benchmarks/quality.py`` (6 sequences, 2 Stage 2 seeds): 1 mm lowers Chamfer_pts of Stage 1
    from 0.292 to 0.272 and of Stage 2 from 0.198 to 0.192 (1e-4 m^2); 2 mm made Stage 2 worse on
    the shoulder-length and short styles."""
    outside_tolerance: float = 0.5
    """Distance from the target silhouette, in fitting pixels, that :attr:`LossWeights.outside` leaves
    alone (the masks are soft and the head poses off by about a pixel)."""
    depth_head: bool = False
    """Where the depth targets also cover the visible head (``DepthConfig.context``), the depth term
    compares the fitted head's own depth there with them, in the same alignment as the hair
    (:func:`vid2haircut.fit.scene.image_losses`): the head then fixes where the hair lies in depth,
    which a relative depth of the hair alone leaves open by a shift. Off (default): the hair only.
    Measured on four sequences of the quality benchmark with such targets: Stage 2 0.0421 against
    0.0387 (1e-4 m^2), its hair thinner, since the depth the guides render is not lowest at the
    truth (``benchmarks/RESULTS.md``, "How full the hair is")."""
    min_bend_radius: float = 0.003
    """Tightest bend (metres) that :attr:`LossWeights.bend` leaves alone."""
    map_res: int = 32
    """Hair map resolution R when there is no prior (with a prior: the network's)."""
    mask_threshold: float = 0.5
    """Texels whose baldness-mask value reaches this carry a guide strand."""
    weights: LossWeights = field(default_factory=lambda: LossWeights(depth=0.01))
    """Loss weights (Stage 1 uses silhouette, direction, depth, penetration and bend only; depth 0.01 as
    Im2Haircut, penetration 1e4 as Vid2Haircut: Im2Haircut's 0.3 leaves strands inside the head)."""
    render: RenderSettings = field(default_factory=RenderSettings)
    """Guide rendering settings (the binned compositing model: with the exact one the first quality
    draw's Stage 1 gave 0.0738 / 0.2567 against 0.0731 / 0.2567, Chamfer_pts 1e-4 m^2 /
    Chamfer_angle, worse on four of six styles; Stage 1's 100 steps take ~5 s either way)."""
    n_dense: int = 10000
    """Dense strands decoded for the output."""
    length_spread: float = LENGTH_SPREAD
    """Relative spread of the dense strands' lengths (see :data:`LENGTH_SPREAD`; 0 = even ends)."""
    tip_scatter: float = 0.0
    """Per-axis fan-out of the dense strands' tips, metres (see :data:`vid2haircut.fit.components.TIP_SCATTER_MEASURED`; 0 = off)."""
    carve_tolerance: float = CARVE_TOLERANCE
    """Silhouette carving of the dense strands with this stage's keyframes, fitting pixels (see
    :data:`CARVE_TOLERANCE`; 0 = off)."""
    carve_min_fraction: float = 0.5
    """A carved strand is cut before its first point outside the silhouettes only when at least this
    fraction of the points from there to the tip are outside too (:func:`vid2haircut.fit.carve.carve_lengths`)."""
    device: str = "cpu"
    """Torch device."""
    seed: int = 0
    """Seed of everything random (dense root sampling, frame codes)."""


@dataclass
class Stage2Config:
    """Stage 2: joint refinement over all keyframes (Vid2Haircut)."""

    iterations: int = 600
    """Total optimisation steps (method.md: ~800 on a GPU; 600 here for the CPU budget: 300 instead
    gave mean Chamfer_pts 0.103 against 0.096 on the quality benchmark's six sequences, seed 0,
    through 200,000-point subsets; with exact scores 1000 steps give 0.0623 / 0.2398 rad against
    0.0642 / 0.2384 at 1.7x the time, ``benchmarks/stage2_sweep.py``, first draw, seed 0, with an
    opaque silhouette)."""
    canonical_steps: int = 300
    """Steps with the canonical hair only, before the deformation MLP is switched on (method.md: 300)."""
    ramp_steps: int = 100
    """Steps over which the deformation is ramped in linearly from 0 to 1 (method.md: 100)."""
    n_keyframes: int = 6
    """Keyframes used: the reference, then the others in farthest-(yaw, pitch) order (all when fewer exist)."""
    frames_per_step: int = 0
    """Keyframes rendered per step (0 = all; fewer = a deterministic rotating subset)."""
    lr_z: float = 0.02
    """Learning rate of the hair map Z (whitened units, for the first component)."""
    lr_decay_steps: int = 0
    """Over the last this many steps every learning rate falls along a half cosine to ``lr_final``
    times its value (:func:`vid2haircut.fit.trainer.lr_decay_factor`; 0 = constant)."""
    lr_final: float = 0.1
    """Learning-rate factor at the last step when ``lr_decay_steps`` > 0."""
    lr_gain_power: float = 0.5
    """Per-component step size (s_k / s_0) ** power of Z (see :class:`vid2haircut.fit.scene.ZMap`)."""
    z_optimizer: str = "shared_adam"
    """Optimiser of Z: "shared_adam" (:mod:`vid2haircut.fit.optim`) or "adam"."""
    length_step_ref: float = 0.15
    """As :attr:`Stage1Config.length_step_ref` (Stage 2 on the short hairstyle: 0.164 -> 0.096,
    bangs 0.238 -> 0.190)."""
    penetration_margin: float = 0.001
    """As :attr:`Stage1Config.penetration_margin`."""
    outside_tolerance: float = 0.5
    """As :attr:`Stage1Config.outside_tolerance`."""
    depth_head: bool = False
    """As :attr:`Stage1Config.depth_head`."""
    lr_mlp: float = 1.0e-3
    """Adam learning rate of the deformation MLP and texel embeddings (method.md: 1e-2). Adam's first
    steps move each of the 128 zero-initialised output weights by about the learning rate, and the
    Softplus features they multiply are all positive, so at 1e-2 one step moves the output by about
    1, the whole clamp range: the field either sits at rest, held there by the canonical term, or
    jumps to the clamp in every frame and stays (the clamp has no gradient), bob 0.065 against 0.057
    without the canonical term. At 1e-3 it follows the sway (``benchmarks/sway_probe.py``: bob tips
    0.8-6.2 mm in the turned keyframes, along the truth's sway in 4 of 5), and ``benchmarks/quality.py``
    (6 sequences, seeds 0 and 1, Chamfer_pts 1e-4 m^2, the earlier 300 Stage 2 steps) gives 0.1023
    against 0.1036 at 1e-2; without deformation 0.1032. With 600 steps the tips move 1.9-7.3 mm."""
    lr_codes: float = 1.0e-3
    """Adam learning rate of the frame codes (method.md: 1e-3)."""
    max_offset: float = 0.008
    """Largest deformation offset at a strand tip, metres (method.md: 8 mm)."""
    code_init_std: float = 0.3
    """Standard deviation of the initial frame codes: with the published lr 1e-3 and codes near 0,
    the frames stay indistinguishable for hundreds of steps and the field does not move. Measured on
    ``benchmarks/quality.py`` (6 sequences, Stage 2 seeds 0 and 1, Chamfer_pts 1e-4 m^2): std 1
    gives 0.186 / 0.198, std 0.3 gives 0.190 / 0.192 (the same mean, an eighth of the spread), and
    with it every switch ablation is worse than the full method on average."""
    smooth_length_scale: float = 0.01
    """Edge-preserving scale of the length smoothness, metres (:func:`vid2haircut.fit.losses.robust`:
    residuals well above it, such as the edge of a fringe, are not smoothed; 0 = plain L1). Measured
    on ``benchmarks/quality.py``: 0.01 (with 0.1 below) lowers Chamfer_pts of Stage 2 from 0.132 to
    0.118 (1e-4 m^2; the bangs sequence from 0.260 to 0.205)."""
    smooth_tip_scale: float = 0.01
    """Edge-preserving scale of the tip-height smoothness, metres (0 = plain L1)."""
    smooth_direction_scale: float = 0.1
    """Edge-preserving scale of the direction smoothness on 1 - cos (a parting is not pulled
    together; 0 = plain)."""
    min_bend_radius: float = 0.003
    """Tightest bend (metres) that :attr:`LossWeights.bend` leaves alone."""
    depth_align: str = "affine"
    """How the depth term brings the rendered depth to the targets' relative scale, per keyframe
    (:func:`vid2haircut.fit.image_terms.depth_loss`): "affine" (default; the least-squares scale and
    shift) or "quantile" (the render's own 5% / 95% quantiles to 0 / 1, as the targets are made,
    which moves with wherever the rendered and target masks differ). Measured on
    ``benchmarks/quality.py`` (12 sequences, seed 0, Chamfer_pts 1e-4 m^2, ``benchmarks/RESULTS.md``,
    "The depth term's alignment"): "affine" with depth weight 1 gives 0.0393 / 0.0369 on the two
    draws against 0.0405 / 0.0391 with "quantile" at the published 0.1, lower on 9 of the 12;
    "quantile" at weight 1 gives 0.0405 on the first draw, "affine" at 0.3 0.0400."""
    visibility_unit: str = "strand"
    """What the visibility gate (``switches.use_visibility``) lets frame t update: "strand" (default),
    every segment of the strands with a visible segment in t; "segment", only the segments visible in
    t, as method.md words it (:func:`vid2haircut.fit.visibility.gate_visibility`). Measured on
    ``benchmarks/quality.py`` (12 sequences, seed 0): Stage 2 Chamfer_pts 0.100 with "strand" against
    0.108 with "segment" (1e-4 m^2); the segment gate lets the direction term of a few frames pull
    short strands off the head (short styles 0.081 / 0.085 against 0.131 / 0.123)."""
    anchor_outward: bool = False
    """The anchor (:attr:`LossWeights.anchor`) leaves hidden guide points free to move away from the
    head (along the head's distance gradient at their start): only inward and sideways moves pay.
    Off: measured on ``benchmarks/quality.py`` (tables ``quality_v17`` / ``quality_set2_v17``, seed 0,
    Chamfer_pts 1e-4 m^2) it gives 0.0404 / 0.0383 against 0.0393 / 0.0369, better on the bob and
    side-parted styles of both draws (bob 0.0297 and 0.0246 against 0.0318 and 0.0282) and worse on
    the other four (``benchmarks/RESULTS.md``, "The hair that no keyframe shows: too flat in the upper
    back")."""
    pca_change: bool = False
    """The PCA consistency (``weights.pca``) compares the change Stage 2 makes to the coefficients
    (z - z_start) instead of the coefficients themselves: an unobserved texel moves as its
    neighbours move and keeps the detail of its start map. Off: on the six ``quality_v22`` sequences
    (seed 0, same AMD machine and Stage 1) it gives 0.0344 / 0.2354 (weight 1) and 0.0344 / 0.2365
    (weight 10) against 0.0349 / 0.2323 for the default, the same trade as no PCA consistency at all
    (``benchmarks/RESULTS.md``, "PCA consistency on the change from the start map")."""
    pca_from: int = 10
    """First PCA component the consistency (``weights.pca``) covers: 0, every component; k, only the
    finer components k.. (the coarse ones, length and overall sweep, are left to the anchor and the
    smoothness); none when the map has no more than k components. 10, the coarse-to-fine split of
    method.md: on the six ``quality_v22`` sequences (seed 0, same AMD machine and Stage 1) Stage 2
    gives 0.0346 / 0.2324 against 0.0349 / 0.2323 with every component (Chamfer_pts 1e-4 m^2 /
    Chamfer_angle), lower in Chamfer_pts on five of six; mixing the two runs' maps showed the angle
    gain of the term in the fine components and its Chamfer_pts cost mostly in the coarse ones
    (``benchmarks/RESULTS.md``, "PCA consistency on the fine components only")."""
    smooth_direction_from: int = 5
    """First PCA component the direction smoothness moves: the term sees the strands of the whole map
    but its gradient reaches only components smooth_direction_from.. (0, every component). Mixing
    the hair maps of the default run and of the run without smoothness by component showed the
    smoothness's Chamfer_pts cost in components 0..4 and its Chamfer_angle gain in the finer ones.
    On the six ``quality_v22`` sequences (seed 0, same AMD machine and Stage 1, Chamfer_pts 1e-4 m^2
    / Chamfer_angle): 5 for both terms gives 0.0342 / 0.2325 against 0.0346 / 0.2324 with every
    component (lower on four of six) and 0.0342 / 0.2417 without smoothness; 5 for the direction
    term alone 0.0346 / 0.2335 (``benchmarks/RESULTS.md``, "Smoothness on the fine components only")."""
    smooth_length_from: int = 5
    """The same for the length smoothness (0, every component; 5, measured with
    :attr:`smooth_direction_from`)."""
    smooth_seen_weight: float = 1.0
    """Factor on both smoothness terms of the guides some keyframe has observed (see
    :attr:`observed_fraction`; a neighbour pair takes the mean of its two guides): 1, every guide
    alike; 0, the smoothness shapes only the guides that no keyframe shows, the images alone the
    others."""
    smooth_unseen_weight: float = 1.0
    """The same factor on the guides no keyframe has observed (0: the smoothness shapes only the seen
    guides). Screened on two ``quality_v22`` sequences (shoulder-length and short, seed 0): 0 gives
    0.0321 / 0.2407 against 0.0326 / 0.2341 with 1 and 0.0322 / 0.2453 without smoothness; a
    smooth_seen_weight of 0 gives 0.0327 / 0.2380. On all six sequences 0 is worse than 1 (0.0345 /
    0.2380 against 0.0342 / 0.2325; the bob 0.0286 against 0.0261), so both stay 1
    (``benchmarks/RESULTS.md``, "Which guides the smoothness cost lies in")."""
    smooth_direction_form: str = "relative"
    """What the direction smoothness penalises of neighbouring segments
    (:func:`vid2haircut.fit.losses.smoothness_losses`): "absolute", 1 - cos of their directions;
    "relative" (default), only their loss of alignment against the same pair at the start of Stage 2,
    relu(cos_start - cos), so the fanning out of the start's hair is kept while a guide that turns
    drags its neighbours along; "change", the difference of their changes of direction since the
    start. Measured on the six ``quality_v22`` sequences (Stage 2 seed 0, one Intel Xeon build,
    Chamfer_pts 1e-4 m^2 / Chamfer_angle): "relative" with ``weights.smooth_direction`` 3 gives
    0.0344 / 0.2300 against 0.0346 / 0.2337 for "absolute" at 0.3 (the default before) and
    0.0346 / 0.2416 without smoothness; on three of them "relative" at 0.3 and 1 and "change" at 0.3
    were no better (``benchmarks/RESULTS.md``, "The direction smoothness against the start")."""
    observed_fraction: float = 0.05
    """A texel counts as observed when at least this fraction of its segments is visible in some keyframe."""
    extend_unobserved: bool = False
    """Guides that no keyframe observes at the start (the back) also move by the harmonic extension,
    over the scalp map, of the change Stage 2 makes to the observed guides (e.g. the sides grow
    longer, so does the back); see :attr:`vid2haircut.fit.stage2.Stage2Model.z`. The anchor holds the
    followers' own coefficients, not the change they follow. Off: measured on the first draw of
    ``benchmarks/quality.py`` (table ``quality_v17``, seed 0, Chamfer_pts 1e-4 m^2 / Chamfer_angle) it
    gives 0.0397 / 0.2369 against 0.0393 / 0.2375, better on the short (0.0239 against 0.0284) and wavy
    (0.0485 against 0.0530) styles and worse on the other four (``benchmarks/RESULTS.md``, "The hair
    that no keyframe shows: too flat in the upper back")."""
    render_dense: int = 2000
    """Draw this many dense strands, decoded from the hair map as the output is (differentiably;
    uneven ends, carving and the push out of the head left out), in the image terms instead of the
    guides (0: the guides throughout), from :attr:`dense_from_step` on; the visibility gate then acts
    on them, while the anchor and the PCA consistency still take what the guides show (a forward
    render of the guides). The deformation field is evaluated at the guides, and each dense strand
    takes the offsets of the guide nearest its root; the penetration of the moved hair is the moved
    guides' (the dense strands, decoded without the push, reach into the head where the guides do
    not: bob, 1.6% of their points more than 1 mm inside against 0%, and a penetration term on them,
    moved or not, made Stage 2 worse: ``benchmarks/RESULTS.md``, "Drawing the dense hair in Stage 2's
    image terms"). The guides are 4 mm wide and translucent and stand for the hair between them;
    the dense strands draw the hair as the output has it. Measured on ``benchmarks/quality.py``
    (seed 0, Chamfer_pts 1e-4 m^2): 2000 from step 300 gives 0.0360 and 0.0342 on its two draws
    against 0.0393 and 0.0369 with the guides throughout, at 1.36x the time."""
    dense_from_step: int = -1
    """With ``render_dense``: the steps before this one still draw the guides, the dense strands
    are drawn from it on (negative: from :attr:`canonical_steps`, where the deformation field starts).
    Measured (2000 dense strands, seed 0, Chamfer_pts 1e-4 m^2): from step 300, the end of the
    canonical steps, Stage 2 gives 0.0360 and 0.0342 on the two draws of ``benchmarks/quality.py``;
    from step 0 0.0408 and 0.0339, as the wavy style fails (0.0530 -> 0.0745), and from step 150 the
    wavy style fails again (0.0764; ``benchmarks/RESULTS.md``, "Drawing the dense hair in Stage 2's
    image terms")."""
    dense_width: float = 0.001
    """Short-axis size of the dense strands' Gaussians with ``render_dense`` (in place of
    ``render.strand_width``, which stays the guides'). Measured on ``benchmarks/quality.py`` (seed
    0, Chamfer_pts 1e-4 m^2 / Chamfer_angle, ``benchmarks/stage2_sweep.py``): 1 mm gives 0.0354 /
    0.2328 and 0.0332 / 0.2577 on its two draws against 0.0361 / 0.2338 and 0.0337 / 0.2588 at 1.5
    mm, better on 8 of the 12 sequences, in the same time (``benchmarks/RESULTS.md``, "The dense
    strands' width and the fitting resolution")."""
    dense_silhouette_opacity: float = 1.0
    """Peak opacity of the dense strands in the silhouette term with ``render_dense`` (in place of
    ``render.silhouette_opacity``, which stays the guides')."""
    dense_vis_weight: float = 0.3
    """With ``render_dense``: the compositing weight at which a dense strand's segment counts as
    visible to the visibility gate (in place of ``render.vis_weight``, which stays the guides' and
    drives the observed-texel test and the anchor)."""
    gate_bins_every: int = 5
    """With the exact compositing model (``render.compositing`` "exact", or "auto" on the CPU; the default is
    the bins): the visibility that the gate (and the hidden-direction term, and before the dense strands
    the observed-texel test) takes from Stage 2's render with gradients comes from a forward render of
    the same strands with the binned model instead, made at every step divisible by this (and when the
    frames or strands change; 0: the exact render's own). The exact model's visibility (alpha T at a
    pixel) gating its own gradients fails on the wavy style of the first draw (Chamfer_pts 0.0609 and
    0.0635 for two seeds against the bins' 0.0465); the binned model's visibility with the exact images
    does not (0.0480 and 0.0476 every step, 0.0483 every 5 steps, 0.0489 every 20, through a diagnostic
    script). At 5 the first draw's Stage 2 gives 0.0347 / 0.2240 and at 10 0.0348 / 0.2242, against the
    bins' 0.0344 / 0.2237 the same day (``benchmarks/RESULTS.md``, "Exact compositing on the wavy style:
    the visibility gate"). A checkpoint holds the binned visibility in use, so a resumed fit is the
    same."""
    hidden_direction_from: str = "render"
    """What the hidden-direction term (``weights.hidden_direction``) aligns a segment the gate shuts
    with: "render", the rendered direction of the fitted hair drawn over it in that keyframe
    (detached; a smoothness across layers, so no keyframe's image terms reach what it does not
    show), or "target", that keyframe's target direction at its pixel (measured, not kept:
    ``benchmarks/RESULTS.md``, "The segments the visibility gate shuts")."""
    weights: LossWeights = field(default_factory=lambda: LossWeights(depth=1.0, smooth_direction=3.0,
                                                                     hidden_direction=0.1))
    """Loss weights (depth 1 rather than the published 0.1, measured with ``depth_align: affine``;
    see :attr:`depth_align`; direction smoothness 3 with :attr:`smooth_direction_form` "relative",
    whose penalty is zero for every pair that stays as aligned as at the start; the hidden-direction
    term 0.1, with visibility masking only, against the rendered direction over the segment
    (:attr:`hidden_direction_from`); measured on ``benchmarks/quality.py``'s six sequences in
    ``benchmarks/RESULTS.md``, "The segments the visibility gate shuts")."""
    switches: Switches = field(default_factory=Switches)
    """Ablation switches."""
    render: RenderSettings = field(default_factory=lambda: RenderSettings(size=224))
    """Guide rendering settings; the fitting resolution is 224 pixels (Stage 1: 160). Measured on
    ``benchmarks/quality.py`` (seed 0, Chamfer_pts 1e-4 m^2 / Chamfer_angle, with 1 mm dense
    strands): 224 gives 0.0342 / 0.2324 on the first draw against 0.0356 / 0.2338 at 160 (better
    or level on all six; 0.0346 / 0.2324 in ``quality_v22`` on an Intel machine, 0.0347 / 0.2315 in
    the README's table, fitted on an AMD one) and 0.0323 / 0.2569 on the
    second against 0.0332 / 0.2577, the targets and renders finer (a pixel spans about 1.9 mm at
    the hair instead of 2.6 mm), at 1.07x the demo's Stage 2 time together with the cheaper
    deformation field (``benchmarks/RESULTS.md``, "The 224-pixel fitting resolution as Stage 2's
    default")."""
    mask_threshold: float = 0.5
    """Texels whose baldness-mask value reaches this carry a guide strand."""
    n_dense: int = 10000
    """As :attr:`Stage1Config.n_dense` (this and the next four only decode the output: changing them
    re-decodes a finished fit, see :data:`vid2haircut.fit.pipeline.DECODING_ONLY`)."""
    length_spread: float = LENGTH_SPREAD
    """As :attr:`Stage1Config.length_spread`."""
    tip_scatter: float = 0.0
    """As :attr:`Stage1Config.tip_scatter`."""
    carve_tolerance: float = CARVE_TOLERANCE
    """As :attr:`Stage1Config.carve_tolerance` (Stage 2 carves with all its keyframes)."""
    carve_min_fraction: float = 0.5
    """As :attr:`Stage1Config.carve_min_fraction`."""
    checkpoint_every: int = 50
    """Write a resumable checkpoint every this many steps (0 = only at the end)."""
    device: str = "cpu"
    """Torch device."""
    seed: int = 0
    """Seed of everything random."""
