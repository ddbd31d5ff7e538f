"""Calibration starts from the whole robot's depth (our extension, issue 13; not in the paper).

In the first frames one end-effector mask rarely fixes the camera: a symmetric gripper matches itself
turned, and a segmenter's ragged outline moves PnP by decimetres. The arm beside it is large and
asymmetric. Pinned at the end-effector's seen centre (centres.py), the camera's rotation is searched
over a fixed set of rotations, each scored by how close the robot mask's back-projected depth lands to
the robot model placed by forward kinematics (truncated nearest-point distance, so a segmenter's false
blobs and a stereo camera's flying pixels count little); the best are refined by trimmed point-to-point
ICP. A biased depth still gives a start near the right basin; the silhouette refinement does the rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from kernel.camera import backproject
from kernel.transforms import inv_T, make_T, transform_points

N_ROTATIONS = 2000  # uniform on SO(3): neighbours about 15 deg apart
TRUNCATE_M = 0.05
MAX_OBSERVED = 600
COARSE_POINTS, COARSE_KEEP = 60, 100  # every rotation is scored on an even tenth of the points, the best on all


@dataclass
class RobotSamples:
    """Surface samples of each robot part (part frame) with their face normals, spread by area over the whole
    robot; seeded."""
    points: list[np.ndarray]
    normals: list[np.ndarray]

    @classmethod
    def of(cls, meshes: list[trimesh.Trimesh], n: int = 4000) -> "RobotSamples":
        areas = np.array([m.area for m in meshes])
        counts = np.maximum(20, np.round(n * areas / areas.sum())).astype(int)
        samples = [trimesh.sample.sample_surface(m, int(c), seed=0) for m, c in zip(meshes, counts)]
        return cls([p for p, _ in samples], [m.face_normals[f] for m, (_, f) in zip(meshes, samples)])

    def placed(self, T_base_parts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every sample and normal in the base frame, the parts placed at `T_base_parts` (n, 4, 4)."""
        return (np.concatenate([transform_points(T, P) for P, T in zip(self.points, T_base_parts)]),
                np.concatenate([N @ T[:3, :3].T for N, T in zip(self.normals, T_base_parts)]))


def observed_points(depth: np.ndarray, mask: np.ndarray, K: np.ndarray, n: int = MAX_OBSERVED) -> np.ndarray:
    """Camera-frame points of the masked pixels with depth, an even subsample of at most n."""
    v, u = np.nonzero(np.asarray(mask, bool) & (np.asarray(depth) > 0))
    if len(u) == 0:
        return np.zeros((0, 3))
    keep = np.linspace(0, len(u) - 1, min(n, len(u))).astype(int)
    return backproject(np.stack([u[keep], v[keep]], 1).astype(float), np.asarray(depth, float)[v[keep], u[keep]], K)


def robot_starts(model_base: np.ndarray, seen: np.ndarray, pivot_base: np.ndarray, pivot_cam: np.ndarray,
                 n_best: int = 3, iterations: int = 20) -> list[np.ndarray]:
    """T_cam_base candidates, best first. model_base: (n, 3) robot model points in the base frame;
    seen: (m, 3) observed robot points in the camera; the pivot is one point known in both frames."""
    if len(seen) < 20 or len(model_base) == 0:
        return []
    tree = cKDTree(model_base)
    R = Rotation.random(N_ROTATIONS, random_state=0).as_matrix()  # R_cam_base candidates
    local = seen - pivot_cam
    coarse = local[np.linspace(0, len(local) - 1, min(COARSE_POINTS, len(local))).astype(int)]
    keep = np.argsort(_score(R, coarse, tree, pivot_base), kind="stable")[:COARSE_KEEP]
    R = R[keep]
    starts = []
    for r in np.argsort(_score(R, local, tree, pivot_base), kind="stable")[:n_best]:
        T = make_T(R[r], pivot_cam - R[r] @ pivot_base)
        starts.append(_icp(T, tree, model_base, seen, iterations))
    return starts


def _score(R: np.ndarray, local: np.ndarray, tree: cKDTree, pivot_base: np.ndarray) -> np.ndarray:
    """Each rotation's mean truncated distance of the pivot-relative points to the model."""
    in_base = np.einsum("rji,mj->rmi", R, local) + pivot_base  # R^T (p - pivot_cam) + pivot_base
    d, _ = tree.query(in_base.reshape(-1, 3), distance_upper_bound=TRUNCATE_M)
    return np.minimum(d, TRUNCATE_M).reshape(len(R), len(local)).mean(1)


def _icp(T_cam_base: np.ndarray, tree: cKDTree, model_base: np.ndarray, seen: np.ndarray,
         iterations: int) -> np.ndarray:
    """Trimmed point-to-point ICP: pairs within a gate that shrinks from 5 to 1.5 cm."""
    for gate in np.geomspace(TRUNCATE_M, 0.015, iterations):
        d, idx = tree.query(transform_points(inv_T(T_cam_base), seen))
        near = d < gate
        if near.sum() < 10:
            break
        T_cam_base, _, _ = trimesh.registration.procrustes(model_base[idx[near]], seen[near], reflection=False,
                                                          scale=False)
    return T_cam_base
