"""Pose and calibration errors, vectorised over frames: ADD and ADD-S as BOP's `add` / `adi`
(bop_toolkit_lib.pose_error; Hinterstoisser et al., ACCV 2012), AUC as YCB-Video (Xiang et al., RSS 2018).

Poses are (n, 4, 4) arrays in metres; a frame without an estimate holds NaN and scores an infinite
ADD / ADD-S (a failure) and NaN for the other errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from syneepose.transforms import inv_T, rotation_angle

CHUNK = 256  # frames per vectorised block: bounds memory at CHUNK x points x 3 floats
_trapezoid = getattr(np, "trapezoid", None) or np.trapz  # NumPy 2 renamed trapz


def model_tree(points: np.ndarray) -> cKDTree:
    """The ADD-S tree over the model points; unbalanced nodes answer near-surface queries faster (measured)."""
    return cKDTree(points, balanced_tree=False, compact_nodes=False)


def _stack(T) -> np.ndarray:
    return np.asarray(T, dtype=float).reshape(-1, 4, 4)


def _valid(T: np.ndarray) -> np.ndarray:
    return np.isfinite(T).all(axis=(1, 2))


def _mean(dist: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """Mean over points (last axis), or the weighted mean when the points stand for cells of the model."""
    return dist.mean(axis=-1) if weights is None else dist @ weights


def add(T_est, T_gt, points: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """ADD (m): mean distance between the model points under the two poses (weighted by `weights`, which sum
    to 1, when the points are a stratified subset of the model: `eval.model_points.query_subset`)."""
    T_est, T_gt = _stack(T_est), _stack(T_gt)
    out = np.full(len(T_gt), np.inf)
    ok = np.flatnonzero(_valid(T_est))
    for chunk in np.array_split(ok, max(1, -(-len(ok) // CHUNK))):
        D = T_est[chunk] - T_gt[chunk]  # (R_e - R_g) p + (t_e - t_g), without posing both copies
        diff = np.einsum("nij,pj->npi", D[:, :3, :3], points) + D[:, None, :3, 3]
        out[chunk] = _mean(np.linalg.norm(diff, axis=-1), weights)
    return out


def adds(T_est, T_gt, points: np.ndarray, tree: cKDTree | None = None, weights: np.ndarray | None = None,
         workers: int = -1) -> np.ndarray:
    """ADD-S (m): mean over GT-posed `points` of the distance to the nearest estimate-posed model vertex.

    The nearest neighbour is searched in `tree`, which must hold the whole evaluation model (BOP's `adi`
    searches all vertices); `points` may be a weighted subset of those vertices (the query side only). Distances are
    rigid-invariant, so the GT-posed points are moved into the estimate's model frame,
    inv(T_est) @ T_gt = I + R_est^T (T_gt - T_est), and one tree serves every frame. Written as I + a
    difference, a perfect estimate scores exactly 0.
    """
    T_est, T_gt = _stack(T_est), _stack(T_gt)
    tree = tree if tree is not None else model_tree(points)
    out = np.full(len(T_gt), np.inf)
    ok = np.flatnonzero(_valid(T_est))
    for chunk in np.array_split(ok, max(1, -(-len(ok) // CHUNK))):
        Rt, D = np.swapaxes(T_est[chunk, :3, :3], 1, 2), T_gt[chunk] - T_est[chunk]
        query = points + np.einsum("nij,pj->npi", Rt @ D[:, :3, :3], points) + (Rt @ D[:, :3, 3:])[:, None, :, 0]
        dist, _ = tree.query(query.reshape(-1, 3), workers=workers)
        out[chunk] = _mean(dist.reshape(len(chunk), len(points)), weights)
    return out


def accuracy_curve(errors, max_error: float, step: float = 1e-5) -> tuple[np.ndarray, np.ndarray]:
    """Thresholds x on [0, max_error] and the fraction of frames with error <= x (NaN/inf never count)."""
    errors = np.sort(np.nan_to_num(np.asarray(errors, dtype=float).ravel(), nan=np.inf))
    if len(errors) == 0:
        raise ValueError("accuracy curve of no frames")
    x = np.linspace(0.0, max_error, int(round(max_error / step)) + 1)
    return x, np.searchsorted(errors, x, side="right") / len(errors)


def auc(errors, max_error: float, step: float = 1e-5) -> float:
    """Area under the accuracy curve on [0, max_error] divided by max_error, x100 (100 = every error 0)."""
    x, frac = accuracy_curve(errors, max_error, step)
    return float(_trapezoid(frac, x) / max_error * 100.0)


def rotation_error_deg(T_est, T_gt) -> np.ndarray:
    T_est, T_gt = _stack(T_est), _stack(T_gt)
    return np.degrees(rotation_angle(T_est[:, :3, :3], T_gt[:, :3, :3]))


def translation_error_mm(T_est, T_gt) -> np.ndarray:
    T_est, T_gt = _stack(T_est), _stack(T_gt)
    return np.linalg.norm(T_est[:, :3, 3] - T_gt[:, :3, 3], axis=-1) * 1000.0


@dataclass
class CalibrationError:
    trans_mm: np.ndarray  # (n,) translation of the camera-to-base pose T_cam_base
    rot_deg: np.ndarray  # (n,)
    points_mm: np.ndarray  # (n, k) per workspace point


def calibration_error(T_cam_base_est, T_cam_base_gt, points_base: np.ndarray) -> CalibrationError:
    """Error of a camera-to-base calibration, plus where it sends workspace points (the paper's targeting
    test): a point p seen by the camera at T_gt p is mapped back to the base by inv(T_est); error |. - p|."""
    T_est, T_gt = _stack(T_cam_base_est), _stack(T_cam_base_gt)
    points_base = np.asarray(points_base, dtype=float).reshape(-1, 3)
    rel = inv_T(T_est) @ T_gt
    moved = np.einsum("nij,kj->nki", rel[:, :3, :3], points_base) + rel[:, None, :3, 3]
    return CalibrationError(trans_mm=translation_error_mm(T_est, T_gt), rot_deg=rotation_error_deg(T_est, T_gt),
                            points_mm=np.linalg.norm(moved - points_base, axis=-1) * 1000.0)
