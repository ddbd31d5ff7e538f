"""Point-pair-feature voting (Drost et al. 2010) refined by point-to-plane ICP, on the masked depth: the
classical model-based peer that needs no learned weights.

OpenCV's `ppf_match_3d` would be the library to use, but its pose clustering (4.10) averages quaternions
without normalising them or aligning their signs (opencv_contrib#3223): on a plain box its poses came out
scaled by ~0.26 and 34-110 deg off. So the voting is written here in numpy, following the paper: pair
features (distance, three angles) quantised and hashed over the model; every scene reference point votes
for (model point, rotation about the normal) through the hash table; peaks become poses, poses are
clustered (votes summed, rotations averaged with SciPy), and the best clusters are refined by ICP. The
voting runs compiled (numba), each scene reference point on its own.

The evaluator runs it as a peer on each frame's masked depth (`--method ppf`); the estimator finds the
whole robot with it when no mask is given (feepe/registration.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from feepe.depth import normal_map
from feepe.icp import SurfaceModel, icp_into_points
from kernel.camera import point_map
from kernel.transforms import make_T


@dataclass
class PpfOptions:
    sampling: float = 0.05  # distance step and voxel size, relative to the model diameter (Drost: 0.05)
    angle_bins: int = 30  # 12 deg
    scene_step: int = 5  # every 5th sampled scene point is a reference point
    max_references: int | None = None  # at most this many reference points: the step grows on a larger scene
    hypotheses: int = 5  # best clusters refined by ICP
    icp_rounds: int = 10
    inlier_m: float = 0.005  # scene points this close to the posed model count as explained
    max_scene_points: int = 4000


def voxel_sample(points: np.ndarray, normals: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """One point per occupied voxel, voxels in lexicographic order of their (x, y, z) indices: the mean point and
    the mean normal (renormalised). The three indices are one integer (an extent of up to 2^21 voxels a side),
    whose 1-D unique and per-column bincounts take a tenth of np.unique over rows and np.add.at (a stereo
    frame's 70,000 points: 46 ms a call), with the same sums in the same order."""
    cells = np.floor(points / voxel).astype(np.int64)
    cells -= cells.min(0, initial=0)
    span = cells.max(0, initial=0) + 1
    _, inverse, counts = np.unique((cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2], return_inverse=True,
                                   return_counts=True)
    sums = [np.bincount(inverse, weights=a[:, k], minlength=len(counts)) for a in (points, normals) for k in range(3)]
    p, n = np.stack(sums[:3], 1, dtype=float), np.stack(sums[3:], 1, dtype=float)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return p / counts[:, None], n


def _to_x_axis(normals: np.ndarray) -> np.ndarray:
    """Rotations taking each normal onto +x (the smallest rotation; a half turn about z for -x)."""
    x = np.array([1.0, 0.0, 0.0])
    axis = np.cross(normals, x)
    s = np.linalg.norm(axis, axis=1)
    c = normals @ x
    angle = np.arctan2(s, c)
    axis = np.where(s[:, None] > 1e-9, axis / np.maximum(s[:, None], 1e-12), [0.0, 0.0, 1.0])
    return Rotation.from_rotvec(axis * angle[:, None]).as_matrix()


class PpfDetector:
    def __init__(self, model: SurfaceModel, opts: PpfOptions | None = None, reach: float | None = None):
        """`reach`: the longest point pair of the model and the scene (m; default the model's diameter). A scene
        part known to span less holds no longer pair, and the model's table shrinks with it."""
        self.opts = opts or PpfOptions()
        self.surface = model
        extent = model.points.max(0) - model.points.min(0)
        self.diameter = float(np.linalg.norm(extent))
        self.reach = self.diameter if reach is None else min(float(reach), self.diameter)
        self.step = self.opts.sampling * self.diameter
        self.points, self.normals = voxel_sample(model.points, model.normals, self.step)
        self.R_ref = _to_x_axis(self.normals)
        if reach is None:
            i, j = np.nonzero(~np.eye(len(self.points), dtype=bool))
        else:
            pairs = cKDTree(self.points).query_pairs(self.reach, output_type="ndarray")
            i, j = np.concatenate([pairs[:, 0], pairs[:, 1]]), np.concatenate([pairs[:, 1], pairs[:, 0]])
        keys, alpha = _pairs(self.points, self.normals, self.R_ref, i, j, self.step, self.opts.angle_bins)
        order, self.first = _hash_table(keys)
        self.ref, self.alpha = i[order], alpha[order]

    def _votes(self, points, normals) -> list[tuple[float, np.ndarray]]:
        """(votes, T_cam_model) of each scene reference point's best (model point, angle)."""
        R_scene = _to_x_axis(normals)
        step = self.opts.scene_step
        if self.opts.max_references:
            step = max(step, -(-len(points) // self.opts.max_references))
        refs = np.arange(0, len(points), step)
        best = _vote(points, normals, R_scene, refs, self.reach, self.first, self.ref, self.alpha, len(self.points),
                     self.step, self.opts.angle_bins, numba.get_num_threads())
        voted = best[:, 0] > 0  # else no neighbour, or no pair the model has
        r, m, b = refs[voted], best[voted, 1], best[voted, 2]
        # T_cam_model = T_s^-1 R_x(angle) T_m, T_m and T_s turning the model and scene reference points' normals
        # onto +x about their points, for every vote at once
        R_x = Rotation.from_euler("x", (b[:, None] + 0.5) * 2 * np.pi / self.opts.angle_bins).as_matrix()
        R_s_t = np.transpose(R_scene[r], (0, 2, 1))
        T = np.zeros((len(r), 4, 4))
        T[:, :3, :3] = R_s_t @ R_x @ self.R_ref[m]
        T[:, :3, 3] = points[r] - np.einsum("nij,nj->ni", R_s_t @ R_x, np.einsum("nij,nj->ni", self.R_ref[m],
                                                                                   self.points[m]))
        T[:, 3, 3] = 1.0
        return [(float(v), T_i) for v, T_i in zip(best[voted, 0], T)]

    def _clusters(self, votes: list[tuple[float, np.ndarray]]) -> list[np.ndarray]:
        """Greedy clusters (within a tenth of the diameter and 2 angle bins), strongest first, averaged. A vote
        joins the first cluster (in the order they were opened) whose first pose is that near (`_greedy_clusters`:
        compiled; comparing each vote with all clusters in numpy took 60 ms of a robot registration's frame)."""
        votes = sorted(votes, key=lambda v: -v[0])
        if not votes:
            return []
        w, T = np.array([v for v, _ in votes]), np.stack([T for _, T in votes])
        label = _greedy_clusters(np.ascontiguousarray(T[:, :3, 3]), np.ascontiguousarray(T[:, :3, :3]),
                                 0.1 * self.diameter, 2 * 2 * np.pi / self.opts.angle_bins)
        weight = [0.0] * (label.max() + 1)
        for c, w_v in zip(label, w):
            weight[c] += w_v
        poses = []
        for c in sorted(range(len(weight)), key=lambda c: -weight[c])[: self.opts.hypotheses]:
            members = np.flatnonzero(label == c)
            R = Rotation.from_matrix(T[members, :3, :3]).mean(weights=w[members]).as_matrix()
            poses.append(make_T(R, np.average(T[members, :3, 3], axis=0, weights=w[members])))
        return poses

    def hypotheses(self, points: np.ndarray, normals: np.ndarray) -> list[np.ndarray]:
        """T_cam_model of the best pose clusters among the votes of the scene's (sampled) points, strongest
        first, before any refinement."""
        return self._clusters(self._votes(points, normals))

    def _refine(self, T: np.ndarray, scene: np.ndarray) -> np.ndarray:
        """Point-to-plane ICP of the model into the scene points, its gate shrinking from a tenth of the model's
        diameter to twice the inlier distance."""
        gates = np.linspace(0.1 * self.diameter, 2 * self.opts.inlier_m, self.opts.icp_rounds)
        return icp_into_points(T, scene, self.surface, gates, self.opts.inlier_m / 2)

    def detect(self, points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, float] | None:
        """T_cam_model and the fraction of scene points it explains; None when the scene is too small."""
        if len(points) < 10:
            return None
        p, n = voxel_sample(points, normals, self.step)
        if len(p) < 4:
            return None
        best, best_fit = None, -1.0
        for T in self.hypotheses(p, n):
            T = self._refine(T, points)
            dist, _ = self.surface.tree.query((points - T[:3, 3]) @ T[:3, :3])
            fit = float(np.mean(dist < self.opts.inlier_m))
            if fit > best_fit:
                best, best_fit = T, fit
        return (best, best_fit) if best is not None else None


@numba.njit(cache=True, nogil=True)
def _greedy_clusters(t, R, radius, max_angle):
    """Each vote's cluster (numbered as opened): the first whose first vote lies within `radius` and `max_angle`
    (kernel.transforms.rotation_angle in scalars) of it, else a new one."""
    label, first, k = np.empty(t.shape[0], np.int64), np.empty(t.shape[0], np.int64), 0
    M = np.empty((3, 3))  # a vote's rotation relative to a cluster's first
    for v in range(t.shape[0]):
        label[v] = -1
        for c in range(k):
            f = first[c]
            if np.sqrt((t[v, 0] - t[f, 0]) ** 2 + (t[v, 1] - t[f, 1]) ** 2 + (t[v, 2] - t[f, 2]) ** 2) >= radius:
                continue
            for i in range(3):
                for j in range(3):
                    M[i, j] = R[v, 0, i] * R[f, 0, j] + R[v, 1, i] * R[f, 1, j] + R[v, 2, i] * R[f, 2, j]
            s = 0.5 * np.sqrt((M[2, 1] - M[1, 2]) ** 2 + (M[0, 2] - M[2, 0]) ** 2 + (M[1, 0] - M[0, 1]) ** 2)
            if np.arctan2(s, 0.5 * (M[0, 0] + M[1, 1] + M[2, 2] - 1.0)) < max_angle:
                label[v] = c
                break
        if label[v] < 0:
            first[k], label[v] = v, k
            k += 1
    return label


@numba.njit(cache=True, nogil=True)
def _pair_key(dx, dy, dz, n, m, step, bins):
    """The quantised feature (distance, three angles) of a pair of points (dx, dy, dz from the first to the second)
    with normals n and m, in scalars: the model's table (`_pairs`) and the scene's votes (`_vote`) read the same
    key."""
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    s = max(dist, 1e-12)
    ux, uy, uz = dx / s, dy / s, dz / s
    a0 = np.arccos(min(max(n[0] * ux + n[1] * uy + n[2] * uz, -1.0), 1.0))
    a1 = np.arccos(min(max(m[0] * ux + m[1] * uy + m[2] * uz, -1.0), 1.0))
    a2 = np.arccos(min(max(n[0] * m[0] + n[1] * m[1] + n[2] * m[2], -1.0), 1.0))
    width = np.pi / bins
    return ((np.int64(np.floor(dist / step)) * bins + np.int64(np.floor(a0 / width))) * bins
            + np.int64(np.floor(a1 / width))) * bins + np.int64(np.floor(a2 / width))


@numba.njit(cache=True, nogil=True)
def _pair_angle(dx, dy, dz, R):
    """The angle of the pair's second point (dx, dy, dz from the first) about the first's normal once R turns
    that normal onto +x."""
    ly = R[1, 0] * dx + R[1, 1] * dy + R[1, 2] * dz
    lz = R[2, 0] * dx + R[2, 1] * dy + R[2, 2] * dz
    return np.arctan2(lz, ly)


@numba.njit(cache=True, nogil=True, parallel=True)
def _pairs(points, normals, R_ref, i, j, step, bins):
    """The model's hash table entries: each pair (i -> j)'s key and the angle of j about i's normal,
    on both cores (in numpy a robot's table of a million pairs took 0.17 s, half its first frame's registration)."""
    keys, alpha = np.empty(i.shape[0], np.int64), np.empty(i.shape[0])
    for t in numba.prange(i.shape[0]):
        a, b = i[t], j[t]
        dx, dy, dz = points[b, 0] - points[a, 0], points[b, 1] - points[a, 1], points[b, 2] - points[a, 2]
        keys[t], alpha[t] = _pair_key(dx, dy, dz, normals[a], normals[b], step, bins), _pair_angle(dx, dy, dz, R_ref[a])
    return keys, alpha


@numba.njit(cache=True, nogil=True)
def _hash_table(keys):
    """The pairs ordered by key (as np.argsort(keys, kind="stable")) and where each key's run starts in that
    order (`first[k]:first[k + 1]`), by counting: the keys span about a million values (distance steps x 30^3
    angle bins), and a robot's two million pairs sort in a seventh of argsort's time, while a vote finds its
    run in one read instead of two binary searches."""
    first = np.zeros(keys.max() + 2 if keys.shape[0] else 1, np.int64)
    for k in keys:
        first[k + 1] += 1
    first = np.cumsum(first)
    at, order = first.copy(), np.empty(keys.shape[0], np.int64)
    for t in range(keys.shape[0]):
        order[at[keys[t]]] = t
        at[keys[t]] += 1
    return order, first


@numba.njit(cache=True, nogil=True, parallel=True)
def _vote(S, SN, SR, refs, reach, first, ref, alpha, n_model, step, bins, n_cores):
    """Drost's voting, each reference point on its own: every scene point within `reach` (Drost: the model's
    diameter) forms a pair with it, every model pair of the same key votes for (model point, angle); (votes,
    model point, angle bin) of its peak (the first of equal ones, as np.argmax), votes 0 when nothing voted.
    Reference points run on `n_cores` cores, every n-th on each, each core with one accumulator whose cells count
    only for the reference point that last stamped them: no accumulator of a million cells cleared and searched
    per reference point (the near pass's), and a pair's angle computed only for a key the model has."""
    out = np.zeros((refs.shape[0], 3), np.int64)
    for core in numba.prange(n_cores):
        acc = np.zeros(n_model * bins + 1, np.int64)  # + 1: a turn that rounds up to 2 pi lands past the end
        stamp = np.full(n_model * bins + 1, -1, np.int64)
        for q in range(core, refs.shape[0], n_cores):
            r = refs[q]
            most, peak = 0, 0
            for j in range(S.shape[0]):
                dx, dy, dz = S[j, 0] - S[r, 0], S[j, 1] - S[r, 1], S[j, 2] - S[r, 2]
                if j == r or dx * dx + dy * dy + dz * dz > reach * reach:
                    continue
                key = _pair_key(dx, dy, dz, SN[r], SN[j], step, bins)
                if key + 1 >= first.shape[0] or first[key] == first[key + 1]:
                    continue
                a_scene = _pair_angle(dx, dy, dz, SR[r])
                for t in range(first[key], first[key + 1]):
                    theta = (a_scene - alpha[t]) % (2 * np.pi)
                    cell = ref[t] * bins + np.int64(np.floor(theta / (2 * np.pi) * bins))
                    if stamp[cell] != q:
                        stamp[cell], acc[cell] = q, 0
                    acc[cell] += 1
                    if acc[cell] > most or (acc[cell] == most and cell < peak):
                        most, peak = acc[cell], cell
            out[q, 0], out[q, 1], out[q, 2] = most, peak // bins, peak % bins
    return out


def scene_cloud(depth: np.ndarray, mask: np.ndarray, K: np.ndarray, max_points: int = 4000):
    """Points and camera-facing normals of the masked depth (mask eroded: rims mix surfaces)."""
    normals, valid = normal_map(depth, K)
    keep = valid & (cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    points = point_map(depth, K)[keep]
    step = max(1, int(np.ceil(len(points) / max_points)))
    return points[::step], normals[keep][::step]
