"""kernel.camera.project against the projections it replaced: feepe's (optimize, silhouette, raster, the stereo
re-projection: the same arithmetic, so the same bits), the overlays' homogeneous one and the motion checks'
(other orders of the same arithmetic: equal to rounding)."""

import numpy as np

from kernel.camera import project

K = np.array([[500.0, 0.0, 319.5], [0.0, 400.0, 239.5], [0.0, 0.0, 1.0]])


def _points(n=1000, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(0.2, 3.0, n)])


def test_a_point_lands_where_the_intrinsics_put_it():
    np.testing.assert_array_equal(project(np.array([[0.1, -0.05, 2.0]]), K, min_z=1e-9), [[344.5, 229.5]])
    np.testing.assert_array_equal(project(np.array([0.0, 0.0, 5.0]), K, min_z=1e-9), [319.5, 239.5])


def test_bit_identical_to_feepes_former_projection_with_one_or_many_intrinsics():
    P = _points()
    z = np.maximum(P[:, 2], 1e-6)
    former = np.stack([K[0, 0] * P[:, 0] / z + K[0, 2], K[1, 1] * P[:, 1] / z + K[1, 2]], 1)
    np.testing.assert_array_equal(project(P, K, min_z=1e-6), former)
    # optimize.py's per-match crop intrinsics: one K per point, as (fx, fy, cx, cy) rows before
    scales = np.random.default_rng(1).uniform(0.5, 2.0, len(P))
    Ks = np.array([np.diag([s, s, 1.0]) @ K for s in scales])
    rows = np.column_stack([Ks[:, 0, 0], Ks[:, 1, 1], Ks[:, 0, 2], Ks[:, 1, 2]])
    former = np.stack([rows[:, 0] * P[:, 0] / z + rows[:, 2], rows[:, 1] * P[:, 1] / z + rows[:, 3]], 1)
    np.testing.assert_array_equal(project(P, Ks, min_z=1e-6), former)


def test_equal_to_rounding_to_the_overlays_and_motion_checks_former_orders():
    P = _points()
    uvw = P @ K.T  # eval/overlays.py
    np.testing.assert_allclose(project(P, K, min_z=1e-9), uvw[:, :2] / uvw[:, 2:], rtol=0, atol=1e-12)
    motion = P[:, :2] / np.maximum(P[:, 2], 1e-9)[:, None] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    np.testing.assert_allclose(project(P, K, min_z=1e-9), motion, rtol=0, atol=1e-12)  # a few ulps of 1500 px


def test_points_at_or_behind_the_camera_project_as_at_the_least_depth():
    P = np.array([[0.01, 0.02, 0.0], [0.01, 0.02, -1.0]])
    expected = project(np.array([[0.01, 0.02, 1e-3]]), K, min_z=1e-3)
    np.testing.assert_array_equal(project(P, K, min_z=1e-3), np.repeat(expected, 2, 0))
    assert np.isfinite(project(P, K, min_z=1e-9)).all()
