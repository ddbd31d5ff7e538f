"""Depth alignment (our extension, off in the paper's variants): point-to-plane ICP of the end-effector
model against the masked depth of every key frame at once, through the same camera-to-base unknown.

The paper's L_3D ties each feature match to the depth at its pixel, so a match's quantisation (a grid
step on the template) stays in the pose. Re-associating the depth points with the nearest model surface
point removes that floor; the CAD model is an input of the method already (the templates are rendered
from it).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numba
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from feepe.optimize import (CONVERGED, DAMPING_FACTOR, DAMPING_MAX, DAMPING_MIN, DAMPING_START, DIAG_FLOOR, Term,
                            add_row, compiled_step, cost_of_squares, jacobian_row, robust_sigma, store_sums, sums_of)
from kernel.camera import backproject
from kernel.errors import UserError
from kernel.transforms import inv_T, transform_points


@dataclass
class SurfaceModel:
    points: np.ndarray  # (M, 3) metres, model frame
    normals: np.ndarray  # (M, 3)

    def __post_init__(self):
        self.tree = cKDTree(self.points)

    @classmethod
    def from_ply(cls, path: Path, n_points: int = 4000, seed: int = 0, scale: float = 0.001) -> "SurfaceModel":
        """Evenly spread surface samples with their face normals; BOP models are in mm (scale 0.001)."""
        path = Path(path)
        if not path.is_file():
            raise UserError(f"{path}: no such model; depth alignment needs the end-effector's BOP model")
        mesh = trimesh.load(path, process=False, force="mesh")
        mesh.apply_scale(scale)
        points, faces = trimesh.sample.sample_surface_even(mesh, n_points, seed=seed)
        return cls(np.asarray(points), np.asarray(mesh.face_normals[faces]))


def observed_cloud(depth: np.ndarray, mask: np.ndarray, K: np.ndarray, max_points: int = 600) -> np.ndarray:
    """Camera points of the mask (eroded by 2 px: silhouette pixels mix surfaces), at most `max_points`."""
    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    v, u = np.nonzero(inner & (depth > 0))
    step = max(1, int(np.ceil(len(u) / max_points)))
    uv = np.stack([u[::step], v[::step]], 1).astype(np.float64)
    return backproject(uv, depth[v[::step], u[::step]], K)


WINDOW_BIAS_MAX_M = 0.003  # a larger predicted window bias: the window straddles a link and what lies behind it


def window_bias(z_model: np.ndarray, drawn: np.ndarray, sigma_px: float) -> np.ndarray:
    """How much farther than the model's surface a window-matching stereo camera reads it (m; 0 off `drawn`).
    A matcher finds one disparity per window, about the window's mean inverse depth, so a surface curving away
    from the camera reads farther than its centre lies (Kanade and Okutomi, TPAMI 1994, model the disparity's
    variation inside a window): the front of a cylinder of radius r at depth z by about z^2 s^2 / (2 r f^2). The
    window is a Gaussian of `sigma_px` (s) over the drawn pixels, the model's depth `z_model` rendered there."""
    on = (drawn & (z_model > 0)).astype(np.float32)
    inv = np.where(on > 0, 1.0 / np.maximum(z_model, 1e-6), 0.0).astype(np.float32)
    size = (int(np.ceil(3 * sigma_px)) * 2 + 1,) * 2
    mean_inv = cv2.GaussianBlur(inv, size, sigma_px) / np.maximum(cv2.GaussianBlur(on, size, sigma_px), 1e-12)
    with np.errstate(divide="ignore"):
        return np.where(on > 0, 1.0 / mean_inv - z_model, 0.0)


def without_window_bias(depth: np.ndarray, z_model: np.ndarray, drawn: np.ndarray, sigma_px: float) -> np.ndarray:
    """A stereo camera's depth less its window bias at the model's surface (`window_bias`); no depth where that
    bias exceeds WINDOW_BIAS_MAX_M, as the depth there is neither surface's."""
    bias = window_bias(z_model, drawn, sigma_px)
    return np.where((depth > 0) & (np.abs(bias) <= WINDOW_BIAS_MAX_M), depth - bias, 0.0)


@dataclass
class PlaneTerms:
    base_points: np.ndarray  # (N, 3) the associated model points in the robot base frame
    base_normals: np.ndarray  # (N, 3) their normals in the base frame
    target_cam: np.ndarray  # (N, 3) the observed depth points, camera frame

    @classmethod
    def of_pairs(cls, T_base_model: np.ndarray, model: SurfaceModel, nearest: np.ndarray,
                 target_cam: np.ndarray) -> "PlaneTerms":
        """The observed points `target_cam` with the model points `nearest` (indices) they pair with, the model
        placed at T_base_model: as they are where that is the identity (the robot's surface, placed in the base
        frame by each frame's joint states; a key frame's 12000 pairs are built again at each of its refinements)."""
        points, normals = np.take(model.points, nearest, axis=0), np.take(model.normals, nearest, axis=0)
        if np.array_equal(T_base_model, np.eye(4)):
            return cls(points, normals, target_cam)
        return cls(transform_points(T_base_model, points), normals @ T_base_model[:3, :3].T, target_cam)

    @classmethod
    def joined(cls, parts: list["PlaneTerms"]) -> "PlaneTerms":
        return cls(*(np.concatenate([getattr(p, name) for p in parts] + [np.zeros((0, 3))])
                     for name in ("base_points", "base_normals", "target_cam")))


def _nearest(T_cam_base: np.ndarray, frames: list[tuple[np.ndarray, np.ndarray]],
             model: SurfaceModel | list[SurfaceModel],
             gate_m: float = np.inf) -> tuple[list, list, np.ndarray, np.ndarray]:
    """The frames with depth points and their models, and each point's distance to its nearest model point
    and that point's index (inf and len(model.points) beyond `gate_m`). One model: all frames in one
    KD-tree query; a list (one per frame, e.g. the robot placed by each frame's joint states): one each."""
    models = model if isinstance(model, list) else [model] * len(frames)
    kept = [(f, m) for f, m in zip(frames, models) if len(f[1])]
    frames, models = [f for f, _ in kept], [m for _, m in kept]
    if not frames:
        return [], [], np.zeros(0), np.zeros(0, int)
    in_model = [transform_points(inv_T(T_cam_base @ T_base_ee), cloud) for T_base_ee, cloud in frames]
    if not isinstance(model, list):
        dist, idx = model.tree.query(np.concatenate(in_model), distance_upper_bound=gate_m)
        return frames, models, dist, idx
    found = [m.tree.query(P, distance_upper_bound=gate_m) for m, P in zip(models, in_model)]
    return frames, models, np.concatenate([d for d, _ in found]), np.concatenate([i for _, i in found])


def associate(T_cam_base: np.ndarray, frames: list[tuple[np.ndarray, np.ndarray]],
              model: SurfaceModel | list[SurfaceModel], gate_m: float) -> PlaneTerms:
    """frames: (T_base_ee, observed cloud) each; each observed point pairs with its nearest model point
    within `gate_m` (`model`: one for all frames, or one per frame)."""
    frames, models, dist, idx = _nearest(T_cam_base, frames, model, gate_m)
    ends = np.cumsum([len(cloud) for _, cloud in frames])
    parts = []
    for (T_base_ee, cloud), m, end in zip(frames, models, ends):
        ok = np.isfinite(dist[end - len(cloud):end])
        parts.append(PlaneTerms.of_pairs(T_base_ee, m, idx[end - len(cloud):end][ok], cloud[ok]))
    return PlaneTerms.joined(parts)


CANDIDATES = 4  # model points a depth point's pairing keeps: the nearest of them stays its nearest until the point
# moves by as much as the gap to the next one (seed 197 scene 9's later frames: with the nearest and the second only,
# 1,200 of a frame's 6,700 points searched the KD-tree again a call, with four a median 14; three and six cost more)


@dataclass
class Pairing:
    """One frame's depth points, each with the CANDIDATES model points nearest to it when it was last searched for,
    its place then in the model's frame, and a lower bound on the distance from there to every other model point
    (the farthest candidate's; the search's reach where fewer lay within it). A point moved by d since lies at least
    that bound less d from every other model point, so while a candidate lies nearer, the nearest candidate is its
    nearest (the triangle inequality), whichever point of whichever cloud stands there: the pairing belongs to its
    model alone, and holds for any gate (ICP's rounds shrink theirs and keep one)."""
    model: SurfaceModel
    placed: np.ndarray  # (N, 3) model frame
    candidates: np.ndarray  # (N, CANDIDATES) model point indices, nearest first (len(model.points): none)
    beyond: np.ndarray  # (N,)


def associate_again(T_cam_base: np.ndarray, frame: tuple[np.ndarray, np.ndarray], model: SurfaceModel,
                    gate_m: float, kept: Pairing | None = None) -> tuple[PlaneTerms, Pairing]:
    """`associate` for one frame (T_base_model, observed cloud), the same pairs, with the KD-tree queried again only
    for the points whose candidates (`kept`, found at another calibration) may no longer hold their nearest; and the
    pairing to keep. Points are searched out to twice the gate, so that one with no model point that near stays
    beyond the gate while it moves less than the gate."""
    T_base_model, cloud = frame
    n, reach, n_model = len(cloud), 2.0 * gate_m, len(model.points)
    if kept is None or kept.model is not model or len(kept.placed) != n:
        kept = Pairing(model, np.full((n, 3), np.inf), np.full((n, CANDIDATES), n_model), np.zeros(n))
    placed, nearest = np.empty((n, 3)), np.empty(n, np.int64)
    _still_paired(np.ascontiguousarray(inv_T(T_cam_base @ T_base_model)), np.ascontiguousarray(cloud, dtype=float),
                  kept.placed, kept.candidates, kept.beyond, model.points, gate_m, placed, nearest)
    again = np.flatnonzero(nearest < 0)
    if len(again):
        moved = np.take(placed, again, axis=0)
        dist, idx = model.tree.query(moved, k=CANDIDATES, distance_upper_bound=reach)
        kept = Pairing(model, kept.placed.copy(), kept.candidates.copy(), kept.beyond.copy())
        kept.placed[again], kept.candidates[again] = moved, idx
        kept.beyond[again] = np.minimum(dist[:, -1], reach)  # the reach where fewer lie within it
        nearest[again] = np.where(dist[:, 0] < gate_m, idx[:, 0], n_model)
    paired = np.flatnonzero(nearest < n_model)
    return PlaneTerms.of_pairs(T_base_model, model, nearest[paired], np.take(cloud, paired, axis=0)), kept


@numba.njit(cache=True, nogil=True)
def _still_paired(A, cloud, ref, candidates, beyond, points, gate, placed, nearest):
    """associate_again's test, one pass: each point placed by A (camera to model frame) and its nearest model point
    within the gate (`nearest`; len(points): none) where its candidates settle it - one of them lies nearer than
    every other model point can (`beyond` less how far it moved from `ref`), or neither they nor any other lies
    within the gate - else -1: to be searched for again."""
    n_model = points.shape[0]
    for i in range(cloud.shape[0]):
        for r in range(3):
            placed[i, r] = A[r, 0] * cloud[i, 0] + A[r, 1] * cloud[i, 1] + A[r, 2] * cloud[i, 2] + A[r, 3]
        moved = np.sqrt((placed[i, 0] - ref[i, 0]) ** 2 + (placed[i, 1] - ref[i, 1]) ** 2
                        + (placed[i, 2] - ref[i, 2]) ** 2)
        best, best_d = n_model, np.inf
        for c in range(candidates.shape[1]):
            j = candidates[i, c]
            if j < n_model:
                d = np.sqrt((placed[i, 0] - points[j, 0]) ** 2 + (placed[i, 1] - points[j, 1]) ** 2
                            + (placed[i, 2] - points[j, 2]) ** 2)
                if d < best_d:
                    best, best_d = j, d
        others = beyond[i] - moved  # no other model point lies nearer
        if best_d < others:
            nearest[i] = best if best_d < gate else n_model
        elif best_d >= gate and others > gate:
            nearest[i] = n_model
        else:
            nearest[i] = -1


class PlaneTerm(Term):
    """Point-to-plane residuals, each distance over its own sigma (m); a residual block for `optimize`.
    The normal is held fixed within a step, as usual for point-to-plane."""

    def __init__(self, planes: PlaneTerms, sigma_m: float | np.ndarray):
        self.planes = planes
        self.inv_sigma = np.broadcast_to(1.0 / np.asarray(sigma_m, dtype=float), len(planes.target_cam)).copy()

    def _arrays(self, T_cam_base: np.ndarray) -> tuple:
        pl = self.planes
        return tuple(np.ascontiguousarray(a, dtype=float) for a in (pl.base_points, pl.base_normals, pl.target_cam,
                                                                   self.inv_sigma, T_cam_base))

    def residuals(self, T_cam_base: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        n = len(self.inv_sigma)
        e, J = np.empty((n, 1)), np.empty((n if jacobian else 0, 1, 6))
        _plane_rows(*self._arrays(T_cam_base), e, J)
        return e, (J if jacobian else None)

    def normal_equations(self, T_cam_base: np.ndarray, H: np.ndarray, g: np.ndarray) -> float:
        squares = np.empty(len(self.inv_sigma))
        _plane_pass(*self._arrays(T_cam_base), H, g, squares, True)
        return cost_of_squares(squares)

    def cost(self, T_cam_base: np.ndarray) -> float:
        squares = np.empty(len(self.inv_sigma))
        _plane_pass(*self._arrays(T_cam_base), np.zeros((6, 6)), np.zeros(6), squares, False)
        return cost_of_squares(squares)

    def solve(self, T_init: np.ndarray, max_iterations: int) -> np.ndarray:
        """`optimize(T_init, no matches, OptimizeOptions(max_iterations=...), [self])`'s calibration, its
        Levenberg-Marquardt loop compiled: a registration refines 24 hypotheses by 8 rounds of ICP, and
        optimize's Python around each step outweighed the few thousand rows (cProfile, seed-131 stereo first
        frames: 1.39 s of 2.83 s in 1152 solves)."""
        if not len(self.inv_sigma):
            return T_init
        return _plane_solve(*self._arrays(T_init), max_iterations)

    def __len__(self) -> int:
        return len(self.inv_sigma)


def icp_into_points(T_cam_model: np.ndarray, points: np.ndarray, model: SurfaceModel, gates_m: np.ndarray,
                    sigma_m: float) -> np.ndarray:
    """Point-to-plane ICP of `model` into the scene `points` (camera frame) from T_cam_model: each round pairs the
    points with their nearest model points within its gate (`gates_m`, one per round) and solves on those pairs
    (`PlaneTerm.solve`, 10 steps); it stops early once fewer than 6 points pair. The robot's registration and the
    PPF peer refine their hypotheses so. Each round's pairs are those of `associate`, the KD-tree searched again only
    where the last round's pairing may no longer hold (`associate_again`): the later rounds move the model by
    millimetres."""
    kept, frame = None, (np.eye(4), points)
    for gate in gates_m:
        planes, kept = associate_again(T_cam_model, frame, model, gate, kept)
        if len(planes.target_cam) < 6:
            break
        T_cam_model = PlaneTerm(planes, sigma_m).solve(T_cam_model, max_iterations=10)
    return T_cam_model


@numba.njit(cache=True, nogil=True)
def _plane_normal_equations(points, normals, target, inv_sigma, T):
    """PlaneTerm.normal_equations from zero: H (symmetric), g and the cost."""
    H, g, squares = np.zeros((6, 6)), np.zeros(6), np.empty(points.shape[0])
    _plane_pass(points, normals, target, inv_sigma, T, H, g, squares, True)
    for p in range(6):
        for q in range(p):
            H[p, q] = H[q, p]
    return H, g, np.log1p(squares).sum()


@numba.njit(cache=True, nogil=True)
def _plane_solve(points, normals, target, inv_sigma, T, max_iterations):
    """feepe.optimize.optimize's loop (its damping, its stops; min_decrease and min_step 0) over PlaneTerm alone."""
    damping = DAMPING_START
    H, g, cost = _plane_normal_equations(points, normals, target, inv_sigma, T)
    no_H, no_g, squares = np.zeros((6, 6)), np.zeros(6), np.empty(points.shape[0])
    for _ in range(max_iterations):
        while True:
            A = H.copy()
            for p in range(6):
                A[p, p] += damping * (H[p, p] + DIAG_FLOOR)
            x = np.linalg.solve(A, -g)
            T_new = compiled_step(T, x)
            _plane_pass(points, normals, target, inv_sigma, T_new, no_H, no_g, squares, False)
            cost_new = np.log1p(squares).sum()
            if cost_new <= cost or damping > DAMPING_MAX:
                break
            damping *= DAMPING_FACTOR
        if cost_new > cost:
            break
        T, damping = T_new, max(damping / DAMPING_FACTOR, DAMPING_MIN)
        H, g, cost = _plane_normal_equations(points, normals, target, inv_sigma, T)
        if max(np.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2), np.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2)) < CONVERGED:
            break
    return T


@numba.njit(cache=True, nogil=True, inline="always")
def _plane_row(points, normals, target, inv_sigma, T, i):
    """Row i of PlaneTerm: n . (target - R p - t) over sigma, with the normal turned by R and held fixed; the
    rotated point and the residual's gradient in the camera point, -n / sigma (optimize.jacobian_row's q and g)."""
    qx = T[0, 0] * points[i, 0] + T[0, 1] * points[i, 1] + T[0, 2] * points[i, 2]
    qy = T[1, 0] * points[i, 0] + T[1, 1] * points[i, 1] + T[1, 2] * points[i, 2]
    qz = T[2, 0] * points[i, 0] + T[2, 1] * points[i, 1] + T[2, 2] * points[i, 2]
    nx = T[0, 0] * normals[i, 0] + T[0, 1] * normals[i, 1] + T[0, 2] * normals[i, 2]
    ny = T[1, 0] * normals[i, 0] + T[1, 1] * normals[i, 1] + T[1, 2] * normals[i, 2]
    nz = T[2, 0] * normals[i, 0] + T[2, 1] * normals[i, 1] + T[2, 2] * normals[i, 2]
    e = (nx * (target[i, 0] - qx - T[0, 3]) + ny * (target[i, 1] - qy - T[1, 3])
         + nz * (target[i, 2] - qz - T[2, 3])) * inv_sigma[i]
    return e, qx, qy, qz, -nx * inv_sigma[i], -ny * inv_sigma[i], -nz * inv_sigma[i]


@numba.njit(cache=True, nogil=True)
def _plane_rows(points, normals, target, inv_sigma, T, e, J):
    """PlaneTerm's rows in one pass and, when J has rows, their Jacobian (optimize.jacobian_row)."""
    for i in range(points.shape[0]):
        e[i, 0], qx, qy, qz, gx, gy, gz = _plane_row(points, normals, target, inv_sigma, T, i)
        if J.shape[0]:
            jacobian_row(J, i, qx, qy, qz, gx, gy, gz)


@numba.njit(cache=True, nogil=True)
def _plane_pass(points, normals, target, inv_sigma, T, H, g, squares, linearise):
    """PlaneTerm's squared rows into `squares` and, when `linearise`, its rows added to the normal equations
    (optimize.add_row)."""
    s = sums_of(H, g)
    for i in range(points.shape[0]):
        e, qx, qy, qz, gx, gy, gz = _plane_row(points, normals, target, inv_sigma, T, i)
        squares[i] = e ** 2
        if linearise:
            s = add_row(s, e, qx, qy, qz, gx, gy, gz)
    store_sums(s, H, g)


def sensor_plane_term(planes: PlaneTerms, T_cam_base: np.ndarray, sigma_0: float, k_z2: float,
                      min_scale: float = 0.25) -> PlaneTerm:
    """Point-to-plane residuals over a sensor noise model sigma(z) = s (sigma_0 + k z^2): the z^2 form of a
    stereo camera's depth RMS (Intel's D435 model: z^2 x subpixel / (f x baseline)), with its scale s
    measured from the data at `T_cam_base` (1.4826 x the median normalised distance, a robust standard
    deviation; at least `min_scale`). Exact depth then pulls hard and a noisy sensor's depth little,
    without naming the sensor; the optimiser's Cauchy kernel has the noise's scale."""
    term = PlaneTerm(planes, sigma_0 + k_z2 * planes.target_cam[:, 2] ** 2)
    if len(planes.target_cam):
        term.inv_sigma = term.inv_sigma / robust_scale(term.residuals(T_cam_base, False)[0][:, 0], min_scale)
    return term


def depth_distances(T_cam_base: np.ndarray, frames: list[tuple[np.ndarray, np.ndarray]],
                    model: SurfaceModel | list[SurfaceModel], sigma_0: float, k_z2: float) -> np.ndarray:
    """The key frames' depth points' distances to the nearest model point, each over the sensor model
    sigma(z) = sigma_0 + k_z2 z^2 of `sensor_plane_term`."""
    frames, _, dist, _ = _nearest(T_cam_base, frames, model)
    if not frames:
        return np.zeros(0)
    return dist / (sigma_0 + k_z2 * np.concatenate([cloud[:, 2] for _, cloud in frames]) ** 2)


def depth_agreement(distances: np.ndarray, scale: float) -> float:
    """How well a calibration explains the depth, in [0, 1]: the mean Cauchy weight 1 / (1 + (x / scale)^2)
    of its `depth_distances` x; NaN without depth points. A mask alone can fit a gripper turned 70 deg as
    well as the right pose; its depth then lies centimetres off."""
    return float(np.mean(1.0 / (1.0 + (distances / scale) ** 2))) if len(distances) else float("nan")


def robust_scale(residuals: np.ndarray, min_scale: float = 0.25) -> float:
    """The residuals' robust_sigma, at least `min_scale`: how far the sensor model's sigma is off for these data
    (exact depth: below 1)."""
    return max(robust_sigma(residuals), min_scale) if len(residuals) else 1.0
