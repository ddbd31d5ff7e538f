"""Calibration starts from end-effector positions (feepe/centres.py): exact on noise-free pairs that span
a plane, the rotation about a line found by the sweep, nothing from one place."""

import numpy as np
from scipy.spatial.transform import Rotation

from feepe.centres import CentreTrack, calibration_starts, observed_centre
from kernel.transforms import make_T, rotation_angle, transform_points

T_CAM_BASE = make_T(Rotation.from_euler("xyz", [-2.0, 0.3, 0.7]).as_matrix(), [0.1, -0.2, 1.4])


def _nearest(starts):
    angles = [float(rotation_angle(T[:3, :3], T_CAM_BASE[:3, :3])) for T in starts]
    i = int(np.argmin(angles))
    return np.degrees(angles[i]), np.linalg.norm(starts[i][:3, 3] - T_CAM_BASE[:3, 3])


def test_points_spanning_a_plane_give_the_calibration():
    base = np.random.default_rng(0).uniform(-0.3, 0.3, (6, 3)) + [0.4, 0.0, 0.5]
    starts = calibration_starts(base, transform_points(T_CAM_BASE, base))
    assert len(starts) == 1
    assert np.allclose(starts[0], T_CAM_BASE, atol=1e-9)


def test_points_along_a_line_sweep_the_free_rotation():
    base = np.linspace([0.3, -0.2, 0.4], [0.5, 0.2, 0.6], 5)
    starts = calibration_starts(base, transform_points(T_CAM_BASE, base), n_sweep=12)
    assert len(starts) == 12
    angle_deg, offset_m = _nearest(starts)
    assert angle_deg <= 15.0 + 1e-6  # 30 deg steps
    assert offset_m < 0.3 * np.sin(np.radians(15.0)) * 2  # the rotation about the line's centre moves t


def test_one_place_gives_no_start_and_the_track_keeps_distinct_places():
    track = CentreTrack(centre_ee=[0.0, 0.0, 0.05])
    T = make_T(t=[0.4, 0.0, 0.5])
    for _ in range(3):
        track.add(T, transform_points(T_CAM_BASE, (T @ [0, 0, 0.05, 1])[None, :3])[0])
    assert len(track.base) == 1 and track.starts() == []
    track.add(T, None)
    assert len(track.base) == 1


def test_observed_centre_is_the_mask_centroid_at_the_median_depth():
    K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    mask = np.zeros((240, 320), bool)
    mask[100:141, 200:221] = True  # centroid (210, 120)
    depth = np.where(mask, 0.8, 0.0)
    depth[100, 200:221] = 3.0  # a flying edge row is ignored
    q = observed_centre(depth, mask, K)
    assert np.allclose(q, [50 / 300 * 0.8, 0.0, 0.8])
    assert observed_centre(np.zeros_like(depth), mask, K) is None
