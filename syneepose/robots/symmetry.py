"""Measured symmetries: a rigid T is a symmetry of a mesh when it maps the surface onto itself.

Score = mean distance from T(surface samples) to the closest point of the untransformed surface; a
symmetry holds when the score is at most `tolerance` x diameter (1 % by default).
"""

from __future__ import annotations

import numpy as np
import trimesh

from kernel.transforms import axis_angle_to_R, make_T, transform_points

AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}
CONTINUOUS_STEPS = 36  # a continuous symmetry must hold at every 10 deg step


def diameter(mesh: trimesh.Trimesh) -> float:
    from scipy.spatial.distance import pdist

    hull = mesh.convex_hull.vertices
    return float(pdist(hull).max())


def rotation_about(axis: str, angle: float) -> np.ndarray:
    return make_T(axis_angle_to_R(AXES[axis], angle))


def symmetry_transforms(axis: str, order: int) -> list[np.ndarray]:
    """The non-identity rotations a claim stands for (order 0 = continuous, sampled)."""
    steps = CONTINUOUS_STEPS if order == 0 else order
    return [rotation_about(axis, 2 * np.pi * k / steps) for k in range(1, steps)]


def symmetry_error(mesh: trimesh.Trimesh, T: np.ndarray, n_samples: int = 2000, seed: int = 0) -> float:
    samples, _ = trimesh.sample.sample_surface(mesh, n_samples, seed=seed)
    _, dist, _ = trimesh.proximity.closest_point(mesh, transform_points(T, samples))
    return float(np.mean(dist))


def check_symmetry(mesh: trimesh.Trimesh, axis: str, order: int, tolerance: float = 0.01,
                   n_samples: int = 2000) -> tuple[bool, float]:
    """(holds, worst error as a fraction of the diameter) over every rotation the claim implies."""
    d = diameter(mesh)
    worst = max(symmetry_error(mesh, T, n_samples) for T in symmetry_transforms(axis, order)) / d
    return worst <= tolerance, worst
