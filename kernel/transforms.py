"""Rigid transforms as 4x4 numpy arrays (metres, radians); batched over leading axes."""

import numpy as np
from scipy.spatial.transform import Rotation


def make_T(R=None, t=None) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def rpy_to_R(rpy) -> np.ndarray:
    """URDF roll-pitch-yaw: fixed axes x, y, z (R = Rz(yaw) Ry(pitch) Rx(roll))."""
    return Rotation.from_euler("xyz", rpy).as_matrix()


def R_to_rpy(R: np.ndarray) -> np.ndarray:
    """Inverse of `rpy_to_R`; at pitch = +-90 deg the yaw is set to 0 (the pair is not unique)."""
    pitch = np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0]))
    if np.hypot(R[0, 0], R[1, 0]) > 1e-9:
        return np.array([np.arctan2(R[2, 1], R[2, 2]), pitch, np.arctan2(R[1, 0], R[0, 0])])
    return np.array([np.arctan2(-R[1, 2], R[1, 1]), pitch, 0.0])


def xyz_rpy_to_T(xyz, rpy) -> np.ndarray:
    return make_T(rpy_to_R(rpy), xyz)


def axis_angle_to_R(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues' formula, vectorised over angles: axis (3,), angle (...) -> (..., 3, 3)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    angle = np.asarray(angle, dtype=float)[..., None, None]
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (golden-angle spiral): the template views (syneepose/templates.py) and the
    motion search's viewing directions (feepe/motion.py)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z**2)
    phi = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ T[:3, :3].T + T[:3, 3]


def rotation_angle(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Geodesic angle between rotations (radians), robust near 0 and pi."""
    R = np.swapaxes(R_a, -1, -2) @ R_b
    skew = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = 0.5 * np.linalg.norm(skew, axis=-1)
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.arctan2(s, c)
