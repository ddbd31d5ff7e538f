"""Key-frame joint optimisation (paper eqs. L_2D + lambda L_3D with a Cauchy loss).

The unknown is the camera-to-base pose: key frame i's end-effector pose is `T_cam_base @ T_base_ee_i`,
which is the paper's `p_t @ dp_i` with `dp_i` from forward kinematics. Residuals are per match, as in the
paper's rho(||e||): the reprojection distance in crop pixels over `sigma_px`, and the distance between the
posed model point and the back-projected query depth over `sigma_m`, so lambda = 1 weighs a `sigma_px`
pixel error like a `sigma_m` depth error and the Cauchy loss has unit scale.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numba
import numpy as np

from kernel.camera import project
from kernel.transforms import transform_points

MIN_Z_M = 1e-6  # a match's model point nearer than this (or behind the camera) projects as if this far
# Levenberg's damping of the Gauss-Newton step, H + damping * (diag H + DIAG_FLOOR): it starts at DAMPING_START,
# is multiplied by DAMPING_FACTOR after a trial step that raised the cost and divided by it (down to DAMPING_MIN)
# after one that lowered it; past DAMPING_MAX a solve gives up its trials (the step has all but vanished).
# DIAG_FLOOR keeps H solvable where a direction no residual moves has a zero diagonal. A step smaller than
# CONVERGED (rad and m, each) ends a solve. Start and factor are Numerical Recipes' Levenberg-Marquardt values
# (1e-3, 10); all six were set with the solver (2735d7b) and no measurement of them is recorded.
DAMPING_START, DAMPING_FACTOR, DAMPING_MIN, DAMPING_MAX = 1e-3, 10.0, 1e-7, 1e8
DIAG_FLOOR = 1e-12
CONVERGED = 1e-7


@dataclass
class Observations:
    """Stacked matches of all key frames, model points already moved into the robot base frame."""
    base_points: np.ndarray  # (N, 3) T_base_ee_i @ X
    uv: np.ndarray  # (N, 2) crop pixels
    K: np.ndarray  # (N, 3, 3) the intrinsics of each match's crop
    observed_cam: np.ndarray  # (N, 3) query depth back-projected, camera frame (NaN: no depth)


def stack(frames: list[tuple[np.ndarray, np.ndarray, list]]) -> Observations:
    """frames: (T_base_ee, crop K, candidates) each."""
    base, uv, K, obs = [], [], [], []
    for T_base_ee, Kc, cands in frames:
        for c in cands:
            base.append(transform_points(T_base_ee, c.xyz))
            uv.append(c.uv)
            K.append(np.broadcast_to(Kc, (len(c.uv), 3, 3)))
            obs.append(c.observed)
    if not base:
        return Observations(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 3, 3)), np.zeros((0, 3)))
    return Observations(np.concatenate(base), np.concatenate(uv), np.concatenate(K), np.concatenate(obs))


def _skew_rows(Q: np.ndarray) -> np.ndarray:
    """d(exp(w) Q)/dw at w = 0 for each row: -[Q]x, shape (N, 3, 3)."""
    z = np.zeros(len(Q))
    return -np.stack([np.stack([z, -Q[:, 2], Q[:, 1]], 1), np.stack([Q[:, 2], z, -Q[:, 0]], 1),
                      np.stack([-Q[:, 1], Q[:, 0], z], 1)], 1)


def point_jacobian(Q: np.ndarray) -> np.ndarray:
    """d(exp(w) Q + t + tau)/d(w, tau) at 0, shape (N, 3, 6)."""
    return np.concatenate([_skew_rows(Q), np.broadcast_to(np.eye(3), (len(Q), 3, 3))], 2)


@numba.njit(cache=True, nogil=True, inline="always")
def jacobian_row(J, i, qx, qy, qz, gx, gy, gz):
    """Row i of an (N, 1, 6) Jacobian in the left perturbation of `_step`, for a scalar residual whose gradient
    in the camera point is g, at the rotated model point Q: g @ point_jacobian(Q) = [Q x g, g], in scalars."""
    J[i, 0, 0], J[i, 0, 1], J[i, 0, 2] = qy * gz - qz * gy, qz * gx - qx * gz, qx * gy - qy * gx
    J[i, 0, 3], J[i, 0, 4], J[i, 0, 5] = gx, gy, gz


def projection_jacobian(P: np.ndarray, K: np.ndarray) -> np.ndarray:
    """d uv / dP (N, 2, 3) of `kernel.camera.project` at camera points P (N, 3), one K (N, 3, 3) each."""
    z = np.maximum(P[:, 2], MIN_Z_M)
    dpi = np.zeros((len(P), 2, 3))
    dpi[:, 0, 0] = K[:, 0, 0] / z
    dpi[:, 0, 2] = -K[:, 0, 0] * P[:, 0] / z**2
    dpi[:, 1, 1] = K[:, 1, 1] / z
    dpi[:, 1, 2] = -K[:, 1, 1] * P[:, 1] / z**2
    return dpi


@numba.njit(cache=True, nogil=True, inline="always")
def add_row(s, e, qx, qy, qz, gx, gy, gz):
    """The sums `s` (`sums_of`) with one scalar residual e added as `_add_normal_equations` adds it, its Jacobian
    row [Q x g, g] (`jacobian_row`) formed in registers, not stored. The sums stay in registers too: a pass over
    a key frame's 12000 depth rows kept them in H and g three times slower."""
    j0, j1, j2, j3, j4, j5 = qy * gz - qz * gy, qz * gx - qx * gz, qx * gy - qy * gx, gx, gy, gz
    w = 1.0 / (1.0 + e ** 2)
    w0, w1, w2, w3, w4, w5 = w * j0, w * j1, w * j2, w * j3, w * j4, w * j5
    return (s[0] + w0 * j0, s[1] + w0 * j1, s[2] + w0 * j2, s[3] + w0 * j3, s[4] + w0 * j4, s[5] + w0 * j5,
            s[6] + w1 * j1, s[7] + w1 * j2, s[8] + w1 * j3, s[9] + w1 * j4, s[10] + w1 * j5,
            s[11] + w2 * j2, s[12] + w2 * j3, s[13] + w2 * j4, s[14] + w2 * j5,
            s[15] + w3 * j3, s[16] + w3 * j4, s[17] + w3 * j5,
            s[18] + w4 * j4, s[19] + w4 * j5,
            s[20] + w5 * j5,
            s[21] + w0 * e, s[22] + w1 * e, s[23] + w2 * e, s[24] + w3 * e, s[25] + w4 * e, s[26] + w5 * e)


@numba.njit(cache=True, nogil=True, inline="always")
def sums_of(H, g):
    """H's upper triangle (row by row) and g as the 27 sums `add_row` carries."""
    return (H[0, 0], H[0, 1], H[0, 2], H[0, 3], H[0, 4], H[0, 5], H[1, 1], H[1, 2], H[1, 3], H[1, 4], H[1, 5],
            H[2, 2], H[2, 3], H[2, 4], H[2, 5], H[3, 3], H[3, 4], H[3, 5], H[4, 4], H[4, 5], H[5, 5],
            g[0], g[1], g[2], g[3], g[4], g[5])


@numba.njit(cache=True, nogil=True, inline="always")
def store_sums(s, H, g):
    """The sums back into H's upper triangle and g."""
    k = 0
    for p in range(6):
        for q in range(p, 6):
            H[p, q] = s[k]
            k += 1
    for p in range(6):
        g[p] = s[21 + p]


class Term:
    """An extra residual block over the camera-to-base pose, already divided by its scale. `residuals` defines
    it; the optimiser reads it through `normal_equations` and `cost`, which a term of many rows computes in one
    compiled pass (a key frame's 12000 depth rows' Jacobian alone is 0.6 MB, written and read again each step)."""

    def residuals(self, T_cam_base: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """(N, k) residuals and, when asked, their (N, k, 6) Jacobian in the left perturbation of `_step`."""
        raise NotImplementedError

    def normal_equations(self, T_cam_base: np.ndarray, H: np.ndarray, g: np.ndarray) -> float:
        """Adds J^T W J (its upper triangle) and J^T W e to H and g, W the Cauchy weights 1 / (1 + ||e_i||^2);
        returns the cost sum log(1 + ||e_i||^2)."""
        e, J = self.residuals(T_cam_base, True)
        e = np.ascontiguousarray(e, dtype=float)
        _add_normal_equations(e, np.ascontiguousarray(J, dtype=float), H, g)
        return _cost([e])

    def cost(self, T_cam_base: np.ndarray) -> float:
        return _cost([self.residuals(T_cam_base, False)[0]])

    def __len__(self) -> int:
        return len(self.residuals(np.eye(4), False)[0])


class _Problem:
    """Residual blocks, already divided by their scales: 2D (2 rows per match), 3D (3 rows per match with
    depth), then the extra terms' (depth alignment's point-to-plane rows, the silhouette's contour rows)."""

    def __init__(self, obs: Observations, sigma_px: float, sigma_m: float, w3d: float, terms: Sequence[Term] = ()):
        self.obs, self.sigma_px, self.k3, self.terms = obs, sigma_px, w3d / sigma_m, terms
        self.depth = np.isfinite(obs.observed_cam).all(1) if w3d > 0 else np.zeros(len(obs.uv), bool)

    def _matches(self, T: np.ndarray, jacobian: bool) -> tuple[list, list]:
        """The matches' blocks (2D, then 3D) and, when asked, their Jacobians."""
        if len(self.obs.uv) == 0:
            return [], []
        Q = self.obs.base_points @ T[:3, :3].T
        P = Q + T[:3, 3]
        e2 = project(P, self.obs.K, min_z=MIN_Z_M) - self.obs.uv
        blocks = [e2 / self.sigma_px, (P[self.depth] - self.obs.observed_cam[self.depth]) * self.k3]
        if not jacobian:
            return blocks, []
        dP = point_jacobian(Q)
        return blocks, [(projection_jacobian(P, self.obs.K) @ dP) / self.sigma_px, dP[self.depth] * self.k3]

    def normal_equations(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """H (symmetric), g and the cost at T over every block."""
        H, g = np.zeros((6, 6)), np.zeros(6)
        blocks, jacobians = self._matches(T, True)
        for e, J in zip(blocks, jacobians):
            _add_normal_equations(np.ascontiguousarray(e, dtype=float), np.ascontiguousarray(J, dtype=float), H, g)
        cost = _cost(blocks) + sum(term.normal_equations(T, H, g) for term in self.terms)
        return np.triu(H) + np.triu(H, 1).T, g, cost

    def cost(self, T: np.ndarray) -> float:
        return _cost(self._matches(T, False)[0]) + sum(term.cost(T) for term in self.terms)


@numba.njit(cache=True, nogil=True)
def _add_normal_equations(e, J, H, g):
    """H += J^T W J (its upper triangle) and g += J^T W e for one block, W = 1 / (1 + ||e_i||^2) per
    residual: rho's derivative. One pass over the rows; in NumPy the weighted copy of J alone took longer."""
    for i in range(e.shape[0]):
        s = 0.0
        for a in range(e.shape[1]):
            s += e[i, a] ** 2
        w = 1.0 / (1.0 + s)
        for a in range(e.shape[1]):
            for p in range(6):
                wp = w * J[i, a, p]
                g[p] += wp * e[i, a]
                for q in range(p, 6):
                    H[p, q] += wp * J[i, a, q]


def robust_sigma(residuals: np.ndarray) -> float:
    """1.4826 x the median absolute residual: a normal distribution's standard deviation, which outliers
    barely move; the scale the residuals' Cauchy kernel is measured at (depth's sensor model, each mask)."""
    return 1.4826 * float(np.median(np.abs(residuals)))


def _cost(blocks: list) -> float:
    return float(sum(np.log1p(np.sum(e**2, 1)).sum() for e in blocks))


def cost_of_squares(squares: np.ndarray) -> float:
    """`_cost` of one block of scalar rows from their squares, as a compiled pass writes them: NumPy's vectorised
    log1p takes a fifth of a compiled loop's, and the sum is the very same."""
    return float(np.log1p(squares).sum())


def _step(T: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A left perturbation: rotation vector x[:3] applied to the rotation, x[3:] added to the translation."""
    out = T.copy()
    out[:3, :3] = cv2.Rodrigues(x[:3])[0] @ T[:3, :3]  # a tenth of SciPy's Rotation's per-call cost
    out[:3, 3] = T[:3, 3] + x[3:]
    return out


@numba.njit(cache=True, nogil=True)
def compiled_step(T, x):
    """`_step` in a compiled loop: the rotation vector's matrix by Rodrigues' formula, as cv2.Rodrigues forms it
    (the identity below machine epsilon)."""
    theta = np.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2)
    R = np.eye(3)
    if theta >= np.finfo(np.float64).eps:
        c, s = np.cos(theta), np.sin(theta)
        rx, ry, rz = x[0] / theta, x[1] / theta, x[2] / theta
        r = (rx, ry, rz)
        skew = np.array([[0.0, -rz, ry], [rz, 0.0, -rx], [-ry, rx, 0.0]])
        for i in range(3):
            for j in range(3):
                R[i, j] = (c if i == j else 0.0) + (1.0 - c) * r[i] * r[j] + s * skew[i, j]
    out = T.copy()
    for i in range(3):
        for j in range(3):
            out[i, j] = R[i, 0] * T[0, j] + R[i, 1] * T[1, j] + R[i, 2] * T[2, j]
        out[i, 3] = T[i, 3] + x[3 + i]
    return out


def _size(x: np.ndarray) -> float:
    """A step's size: the larger of its rotation (rad) and translation (m)."""
    return max(np.linalg.norm(x[:3]), np.linalg.norm(x[3:]))


@dataclass
class OptimizeOptions:
    lam: float = 1.0
    sigma_px: float = 2.0  # crop pixels
    sigma_m: float = 0.005
    max_iterations: int = 30  # accepted steps at most (set with the solver, 2735d7b; no measurement recorded)
    # stop once a Gauss-Newton step predicts less than this fraction of the cost (0: never, as the paper's
    # variants run); else a converged solve keeps raising the damping through ten trials that all fail.
    # The refinement's value: estimator.MIN_DECREASE
    min_decrease: float = 0.0
    # stop once a damped step that failed moves the pose less than this (rad and m; 0: never, as the paper's
    # variants run): more damping only shrinks it, and a converged solve spent most of its trials so.
    # The refinement's value: estimator.MIN_STEP
    min_step: float = 0.0


def optimize(T_init: np.ndarray, obs: Observations, opts: OptimizeOptions,
             terms: Sequence[Term] = ()) -> tuple[np.ndarray, np.ndarray]:
    """The calibration minimising sum rho(||e||^2), rho = Cauchy, and its reprojection errors (px).

    Iteratively reweighted Gauss-Newton with Levenberg damping on analytic Jacobians: the weights
    1 / (1 + ||e||^2) are rho's derivative, so each step is a Gauss-Newton step of the robust cost.
    `terms` adds residual blocks beside the matches' (depth alignment's `feepe.icp.PlaneTerm`, the
    silhouette's contour term).
    """
    if len(obs.uv) == 0 and all(len(t) == 0 for t in terms):
        return T_init, np.zeros(0)
    w3d = float(np.sqrt(opts.lam)) if opts.lam > 0 else 0.0
    problem = _Problem(obs, opts.sigma_px, opts.sigma_m, w3d, terms)
    T, damping = T_init.copy(), DAMPING_START
    H, g, cost = problem.normal_equations(T)
    for _ in range(opts.max_iterations):
        if opts.min_decrease > 0:
            x = np.linalg.lstsq(H, -g, rcond=None)[0]  # of least norm where no residual moves a direction
            if -(g @ x + 0.5 * x @ H @ x) < opts.min_decrease * cost:
                break
        while True:
            x = np.linalg.solve(H + damping * np.diag(np.diag(H) + DIAG_FLOOR), -g)
            T_new = _step(T, x)
            cost_new = problem.cost(T_new)
            if cost_new <= cost or damping > DAMPING_MAX or _size(x) < opts.min_step:
                break
            damping *= DAMPING_FACTOR
        if cost_new > cost:
            break
        T, damping = T_new, max(damping / DAMPING_FACTOR, DAMPING_MIN)
        H, g, cost = problem.normal_equations(T)
        if _size(x) < CONVERGED:
            break
    return T, reprojection_px(T, obs)


def reprojection_px(T_cam_base: np.ndarray, obs: Observations) -> np.ndarray:
    uv = project(obs.base_points @ T_cam_base[:3, :3].T + T_cam_base[:3, 3], obs.K, min_z=MIN_Z_M)
    return np.linalg.norm(uv - obs.uv, axis=1)
