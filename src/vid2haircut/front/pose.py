"""Rigid head pose per keyframe and a shared head shape, fitted to 2D iBUG-68 landmarks.

Two steps:
1. :func:`pnp_pose` — robust PnP per frame (OpenCV EPnP inside RANSAC, then Levenberg-Marquardt
   on the inliers) against the head model's 68 landmarks.
2. :func:`refine_poses` — one joint robust least-squares problem (``scipy.optimize.least_squares``,
   soft-L1 loss) over the shared shape factors and every frame's 6-DoF pose, with a temporal
   smoothness term between consecutive frame indices.

Shape: the head's landmarks are scaled per axis by (scale * width, scale, scale * depth), the
same linear map the proxy head applies for its ``scale``/``width``/``depth`` parameters. The
overall ``scale`` is not observable from a calibrated monocular video (it trades off against
the distance to the camera), so it is held at its prior value unless ``fit_scale`` is set.

Poses are world_from_head (4, 4) rigid transforms, the convention of
``tracking/head_tracking.npz``: x_world = R x_head + t.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from vid2haircut.camera import Camera
from vid2haircut.geometry import axis_angle_to_matrix, make_transform, matrix_to_axis_angle

log = logging.getLogger(__name__)

SHAPE_NAMES = ("scale", "width", "depth")


@dataclass(frozen=True)
class PoseFitConfig:
    """Settings of the landmark pose fit."""

    ransac_threshold_px: float = 8.0
    """RANSAC inlier threshold of the per-frame PnP, pixels (scaled by image size / 512)."""
    robust_scale_px: float = 2.0
    """soft-L1 loss scale of the joint refinement, pixels."""
    fit_scale: bool = False
    """fit the overall head scale too (ill-posed monocularly; kept at ``prior_shape[0]`` if False)."""
    fit_shape: bool = True
    """fit width and depth factors (observable from several views)."""
    prior_shape: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """prior (scale, width, depth)."""
    prior_sigma_log: tuple[float, float, float] = (0.05, 0.05, 0.05)
    """prior standard deviation of log(scale), log(width), log(depth)."""
    smooth_rot_deg: float = 3.0
    """temporal smoothness: expected rotation change between consecutive frames, degrees."""
    smooth_trans_m: float = 0.01
    """temporal smoothness: expected translation change between consecutive frames, metres."""
    landmark_sigma_px: float = 1.0
    """landmark noise used to weigh the reprojection term against the priors, pixels."""


@dataclass
class HeadFit:
    """Result of :func:`fit_head_poses`.

    Attributes:
        head_model: head model name (e.g. "proxy-v1").
        shape: (3,) float64 (scale, width, depth) factors.
        frames: (M,) int64 frame indices.
        world_from_head: (M, 4, 4) float64.
        reprojection_error_px: (M,) mean landmark reprojection error of each frame (inliers).
        inliers: (M, 68) bool landmarks used in the final fit.
        landmarks_2d: (M, 68, 2) float32 the observed landmarks.
    """

    head_model: str
    shape: np.ndarray
    frames: np.ndarray
    world_from_head: np.ndarray
    reprojection_error_px: np.ndarray
    inliers: np.ndarray
    landmarks_2d: np.ndarray
    info: dict = field(default_factory=dict)


def shape_axes(shape: np.ndarray) -> np.ndarray:
    """(3,) (scale, width, depth) -> (3,) per-axis landmark scale factors (x, y, z)."""
    s, w, d = (float(v) for v in shape)
    return np.array([s * w, s, s * d])


def project_landmarks(camera: Camera, world_from_head: np.ndarray, points_head: np.ndarray) -> np.ndarray:
    """(M, 4, 4) poses, (N, 3) head-frame points -> (M, N, 2) pixel coordinates."""
    pts = np.einsum("mij,nj->mni", world_from_head[:, :3, :3], points_head) + world_from_head[:, None, :3, 3]
    return camera.project(pts)[0]


def pnp_pose(points_head: np.ndarray, lmk2d: np.ndarray, camera: Camera,
             cfg: PoseFitConfig = PoseFitConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Robust PnP of one frame.

    Args:
        points_head: (68, 3) landmark positions in the head frame, metres.
        lmk2d: (68, 2) observed pixels (NaN rows ignored).
        camera: the calibrated camera.
    Returns:
        world_from_head (4, 4) float64 and inliers (68,) bool.
    Raises:
        ValueError if fewer than 6 finite landmarks or PnP fails.
    """
    import cv2

    ok_rows = np.isfinite(lmk2d).all(axis=1)
    if ok_rows.sum() < 6:
        raise ValueError(f"PnP needs at least 6 landmarks, got {int(ok_rows.sum())}")
    obj = np.ascontiguousarray(points_head[ok_rows], dtype=np.float64)
    img = np.ascontiguousarray(lmk2d[ok_rows], dtype=np.float64)
    thr = cfg.ransac_threshold_px * max(camera.width, camera.height) / 512.0
    ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, camera.K, None, iterationsCount=200,
                                             reprojectionError=thr, confidence=0.999,
                                             flags=cv2.SOLVEPNP_EPNP)
    if not ok or inl is None or len(inl) < 6:
        raise ValueError("PnP failed (no consistent pose for the landmarks)")
    inl = inl.reshape(-1)
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], camera.K, None, rvec, tvec)
    cam_from_head = make_transform(axis_angle_to_matrix(rvec.reshape(3)), tvec.reshape(3))
    if cam_from_head[2, 3] <= 0:
        raise ValueError("PnP put the head behind the camera")
    inliers = np.zeros(len(lmk2d), dtype=bool)
    inliers[np.flatnonzero(ok_rows)[inl]] = True
    return camera.cam_2_world @ cam_from_head, inliers


def view_angles(camera: Camera, world_from_head: np.ndarray) -> tuple[float, float, float]:
    """Where the camera sits as seen from the head: (yaw_deg, pitch_deg, off_frontal_deg).

    yaw > 0: the camera is towards the head's +x (subject's left); pitch > 0: above the head's
    horizontal plane; off_frontal = angle between the face direction (+z) and the camera.
    """
    head_from_world = np.linalg.inv(world_from_head)
    c = head_from_world[:3, :3] @ camera.center + head_from_world[:3, 3]
    v = c / max(np.linalg.norm(c), 1e-12)
    yaw = np.degrees(np.arctan2(v[0], v[2]))
    pitch = np.degrees(np.arctan2(v[1], np.hypot(v[0], v[2])))
    off = np.degrees(np.arccos(np.clip(v[2], -1.0, 1.0)))
    return float(yaw), float(pitch), float(off)


def _unpack(x: np.ndarray, m: int, cfg: PoseFitConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    log_shape = np.log(np.asarray(cfg.prior_shape, dtype=np.float64))
    free = _free_shape(cfg)
    log_shape[free] = x[: free.sum()]
    poses = x[free.sum():].reshape(m, 6)
    return np.exp(log_shape), poses[:, :3], poses[:, 3:]


def _free_shape(cfg: PoseFitConfig) -> np.ndarray:
    return np.array([cfg.fit_scale, cfg.fit_shape, cfg.fit_shape], dtype=bool)


def refine_poses(points_head: np.ndarray, lmk2d: np.ndarray, inliers: np.ndarray, frames: np.ndarray,
                 camera: Camera, init_world_from_head: np.ndarray,
                 cfg: PoseFitConfig = PoseFitConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Joint robust least squares of shape factors and per-frame poses.

    Args:
        points_head: (68, 3) base landmark positions (shape factors 1).
        lmk2d: (M, 68, 2) observations; inliers: (M, 68) bool rows to use.
        frames: (M,) frame indices (consecutive indices get the smoothness term).
        camera: the calibrated camera; init_world_from_head: (M, 4, 4) starting poses.
    Returns:
        shape (3,) and world_from_head (M, 4, 4).
    """
    from scipy.optimize import least_squares

    m = len(frames)
    w2c = camera.world_2_cam
    cam_from_head = w2c[None] @ init_world_from_head
    x0_pose = np.concatenate([matrix_to_axis_angle(cam_from_head[:, :3, :3]), cam_from_head[:, :3, 3]], axis=1)
    free = _free_shape(cfg)
    log_prior = np.log(np.asarray(cfg.prior_shape, dtype=np.float64))
    x0 = np.concatenate([log_prior[free], x0_pose.reshape(-1)])
    sig_log = np.asarray(cfg.prior_sigma_log, dtype=np.float64)
    obs_i, obs_j = np.nonzero(inliers)
    obs = lmk2d[obs_i, obs_j].astype(np.float64)
    K = camera.K
    order = np.argsort(frames)
    pairs = [(order[k], order[k + 1]) for k in range(m - 1) if frames[order[k + 1]] - frames[order[k]] == 1]
    w_rot = 1.0 / np.radians(cfg.smooth_rot_deg)
    w_tr = 1.0 / cfg.smooth_trans_m

    def residuals(x: np.ndarray) -> np.ndarray:
        shape, rv, tr = _unpack(x, m, cfg)
        rot = axis_angle_to_matrix(rv)  # (M, 3, 3) cam_from_head
        p = points_head * shape_axes(shape)  # (68, 3)
        pc = np.einsum("oij,oj->oi", rot[obs_i], p[obs_j]) + tr[obs_i]
        uv = pc[:, :2] / pc[:, 2:3] @ K[:2, :2].T + K[:2, 2]
        res = [((uv - obs) / cfg.landmark_sigma_px).reshape(-1)]
        res.append((np.log(shape) - log_prior)[free] / sig_log[free])
        if pairs:
            a, b = np.array(pairs).T
            dr = matrix_to_axis_angle(np.swapaxes(rot[a], 1, 2) @ rot[b])  # (P, 3)
            res.append(np.concatenate([dr * w_rot, (tr[b] - tr[a]) * w_tr], axis=1).reshape(-1))
        return np.concatenate(res)

    # Jacobian sparsity: each residual block touches the shape and one or two frames' poses.
    from scipy.sparse import lil_matrix

    ns = int(free.sum())
    n_res = 2 * len(obs_i) + ns + 6 * len(pairs)
    sp = lil_matrix((n_res, len(x0)), dtype=np.int8)
    rows = np.arange(2 * len(obs_i))
    sp[rows, :ns] = 1
    for k in range(6):
        sp[rows, ns + 6 * np.repeat(obs_i, 2) + k] = 1
    for k in range(ns):
        sp[2 * len(obs_i) + k, k] = 1
    r0 = 2 * len(obs_i) + ns
    for q, (a, b) in enumerate(pairs):
        for col in (ns + 6 * a, ns + 6 * b):
            sp[r0 + 6 * q:r0 + 6 * q + 6, col:col + 6] = 1
    f_scale = cfg.robust_scale_px / cfg.landmark_sigma_px
    sol = least_squares(residuals, x0, jac_sparsity=sp, loss="soft_l1", f_scale=f_scale, method="trf",
                        x_scale="jac", max_nfev=200, xtol=1e-10, ftol=1e-10)
    shape, rv, tr = _unpack(sol.x, m, cfg)
    cam_from_head = make_transform(axis_angle_to_matrix(rv), tr)
    return shape, camera.cam_2_world[None] @ cam_from_head


def fit_head_poses(points_head: np.ndarray, lmk2d: np.ndarray, valid: np.ndarray, frames: np.ndarray,
                   camera: Camera, head_model: str = "proxy-v1",
                   cfg: PoseFitConfig = PoseFitConfig(), min_frames: int = 1) -> HeadFit:
    """Fit shared shape + rigid poses to the landmarks of several frames.

    Args:
        points_head: (68, 3) head-model landmarks at shape factors 1, head frame, metres.
        lmk2d: (T, 68, 2) observed landmarks; valid: (T,) bool (False = no face in that frame).
        frames: (T,) frame indices.
        camera: the calibrated camera.
        head_model: name recorded in the result.
        min_frames: raise ValueError when fewer frames with a face remain.
    Returns:
        :class:`HeadFit` over the frames that had a face (others are skipped with a warning).
    """
    frames = np.asarray(frames, dtype=np.int64)
    valid = np.asarray(valid, dtype=bool).copy()
    lmk2d = np.asarray(lmk2d, dtype=np.float64)
    inits, inl = [], []
    for i in range(len(frames)):
        if not valid[i]:
            log.warning("frame %d: no face found, skipped", frames[i])
            continue
        try:
            pose, inliers = pnp_pose(points_head * shape_axes(cfg.prior_shape), lmk2d[i], camera, cfg)
        except ValueError as e:
            log.warning("frame %d: %s, skipped", frames[i], e)
            valid[i] = False
            continue
        inits.append(pose)
        inl.append(inliers)
    n_ok = int(valid.sum())
    if n_ok < max(1, min_frames):
        raise ValueError(f"only {n_ok} of {len(frames)} frames have a usable face (need {max(1, min_frames)})")
    keep = np.flatnonzero(valid)
    inliers = np.stack(inl)
    shape, poses = refine_poses(points_head, lmk2d[keep], inliers, frames[keep], camera, np.stack(inits), cfg)
    # re-label inliers with the refined poses (3x the robust scale), then report the error on them
    proj = project_landmarks(camera, poses, points_head * shape_axes(shape))
    err = np.linalg.norm(proj - lmk2d[keep], axis=-1)  # (M, 68)
    thr = max(3.0 * cfg.robust_scale_px, 1.5 * cfg.ransac_threshold_px * max(camera.width, camera.height) / 512.0)
    inliers = np.isfinite(err) & (err < thr)
    rep = np.array([float(np.mean(e[k])) if k.any() else np.inf for e, k in zip(err, inliers)])
    return HeadFit(head_model=head_model, shape=shape, frames=frames[keep], world_from_head=poses,
                   reprojection_error_px=rep, inliers=inliers,
                   landmarks_2d=lmk2d[keep].astype(np.float32),
                   info={"skipped_frames": [int(t) for t in frames[~valid]]})
