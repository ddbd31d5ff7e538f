"""FEEPE's geometric stages on synthetic data with known answers: crop, PnP, optimisation, memory,
symmetry."""

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from feepe.candidates import Candidate
from feepe.crop import crop_around_mask
from feepe.depth import normal_map
from feepe.icp import (WINDOW_BIAS_MAX_M, PlaneTerm, PlaneTerms, SurfaceModel, associate, associate_again,
                       depth_agreement, depth_distances, robust_scale, window_bias, without_window_bias)
from feepe.matching import best_buddies
from feepe.memory import MemoryEntry, MemoryPool
from feepe.optimize import OptimizeOptions, Term, _step, optimize, robust_sigma, stack
from feepe.silhouette import SilhouetteModel, SilhouetteTerm, mask_view
from feepe.pnp import solve_pnp
from feepe.symmetry import consensus
from kernel.transforms import inv_T, make_T, rotation_angle, transform_points

K = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])


def _pose(rng, distance=0.6):
    return make_T(Rotation.random(random_state=rng).as_matrix(), [rng.normal(0, 0.05), rng.normal(0, 0.05), distance])


def _project(T, X, K):
    P = transform_points(T, X)
    return (P[:, :2] / P[:, 2:]) * [K[0, 0], K[1, 1]] + K[:2, 2]


def test_crop_maps_points_and_intrinsics():
    rng = np.random.default_rng(0)
    mask = np.zeros((240, 320), bool)
    mask[100:140, 200:230] = True
    rgb = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    crop = crop_around_mask(rgb, np.ones((240, 320)), mask, K, 96, 0.2)
    X = np.array([[0.01, -0.02, 0.5], [0.03, 0.0, 0.7]])
    uv = _project(np.eye(4), X, K)
    uv_crop = _project(np.eye(4), X, crop.K)
    np.testing.assert_allclose(uv @ crop.A[:2, :2].T + crop.A[:2, 2], uv_crop, atol=1e-9)  # K moved with the pixels
    assert crop.mask.sum() > 0 and (crop.rgb[~crop.mask] == 0).all()
    # the padded mask box fills the crop: 40 px tall box, 1.2 x padding -> 96 px
    ys = np.nonzero(crop.mask.any(1))[0]
    assert abs((ys.max() - ys.min() + 1) - 96 / 1.2) <= 2
    assert crop_around_mask(rgb, np.ones((240, 320)), np.zeros_like(mask), K, 96, 0.2) is None


def test_normals_of_a_tilted_plane():
    n_true = np.array([0.0, -np.sin(0.4), -np.cos(0.4)])
    u, v = np.meshgrid(np.arange(320.0), np.arange(240.0))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    p0 = np.array([0, 0, 1.0])
    depth = (n_true @ p0) / (rays @ n_true)
    n, valid = normal_map(depth, K)
    assert valid[5:-5, 5:-5].all()
    np.testing.assert_allclose(n[10:-10, 10:-10].reshape(-1, 3), np.tile(n_true, (300 * 220, 1)), atol=1e-6)


def test_best_buddies_are_mutual_and_sorted():
    rng = np.random.default_rng(1)
    t = rng.normal(size=(50, 16))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    perm = rng.permutation(50)
    q = t[perm] + rng.normal(0, 0.01, (50, 16))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    pairs, score = best_buddies(q.astype(np.float32), t.astype(np.float32), max_matches=30)
    assert len(pairs) == 30 and np.all(np.diff(score) <= 0)
    np.testing.assert_array_equal(perm[pairs[:, 0]], pairs[:, 1])


def test_pnp_on_exact_correspondences_is_exact():
    rng = np.random.default_rng(5)
    T = _pose(rng)
    X = rng.uniform(-0.08, 0.08, (60, 3))
    T_est, inlier = solve_pnp(_project(T, X, K), X, K, threshold_px=1.0)
    assert inlier.all()
    assert rotation_angle(T_est[:3, :3], T[:3, :3]) <= 1e-6 and np.linalg.norm(T_est[:3, 3] - T[:3, 3]) <= 1e-6


def test_pnp_recovers_pose_with_outliers():
    rng = np.random.default_rng(2)
    T = _pose(rng)
    X = rng.uniform(-0.08, 0.08, (120, 3))
    uv = _project(T, X, K) + rng.normal(0, 0.3, (120, 2))
    uv[:30] = rng.uniform(0, 320, (30, 2))  # 25 % outliers
    T_est, inlier = solve_pnp(uv, X, K, threshold_px=3.0)
    assert np.rad2deg(rotation_angle(T_est[:3, :3], T[:3, :3])) < 1.0
    assert np.linalg.norm(T_est[:3, 3] - T[:3, 3]) < 0.005
    assert inlier[30:].mean() > 0.95 and inlier[:30].mean() < 0.2
    assert solve_pnp(uv[:5], X[:5], K) is None


def _candidate(T_cam_ee, X, K, rng, noise_px=0.5, depth=True, outliers=0):
    uv = _project(T_cam_ee, X, K) + rng.normal(0, noise_px, (len(X), 2))
    if outliers:
        uv[:outliers] = rng.uniform(0, 320, (outliers, 2))
    obs = transform_points(T_cam_ee, X) if depth else np.full((len(X), 3), np.nan)
    return Candidate(0, T_cam_ee, uv, X, obs, 1.0)


def test_optimisation_recovers_calibration_over_key_frames():
    """8 key frames, 0.5 px noise, 30 % outliers (in 2D and in depth): <= 1 mm and <= 0.1 deg."""
    rng = np.random.default_rng(3)
    T_cam_base = make_T(Rotation.from_euler("xyz", [2.0, 0.3, -0.5]).as_matrix(), [0.1, -0.2, 1.2])
    frames = []
    for _ in range(8):
        T_base_ee = make_T(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.2, 0.2, 3) + [0, 0, 0.4])
        X = rng.uniform(-0.06, 0.06, (80, 3))
        c = _candidate(T_cam_base @ T_base_ee, X, K, rng, outliers=24)
        c.observed[:24] += rng.normal(0, 0.05, (24, 3))  # the outliers' depth is wrong too
        c.observed[24:] += rng.normal(0, 0.001, (56, 3))
        frames.append((T_base_ee, K, [c]))
    T_init = T_cam_base @ make_T(Rotation.from_rotvec([0.1, -0.05, 0.08]).as_matrix(), [0.02, 0.01, -0.02])
    T, r2d = optimize(T_init, stack(frames), OptimizeOptions())
    assert np.rad2deg(rotation_angle(T[:3, :3], T_cam_base[:3, :3])) <= 0.1
    assert np.linalg.norm(T[:3, 3] - T_cam_base[:3, 3]) <= 0.001
    assert np.median(r2d) < 1.0


def test_plane_term_rows_match_numpy_and_finite_differences():
    """PlaneTerm's one-pass rows: n . (target - R p - t) / sigma as written out in NumPy, and a Jacobian that
    central differences under optimize's left perturbation reproduce, the normal held fixed (point-to-plane)."""
    rng = np.random.default_rng(5)
    planes = PlaneTerms(rng.normal(0, 0.05, (200, 3)), rng.normal(size=(200, 3)),
                        rng.normal(0, 0.05, (200, 3)) + [0, 0, 1])
    term = PlaneTerm(planes, rng.uniform(0.001, 0.003, 200))
    T = make_T(Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix(), [0.1, -0.05, 0.9])
    e, J = term.residuals(T, True)
    n = planes.base_normals @ T[:3, :3].T
    expected = np.sum(n * (planes.target_cam - planes.base_points @ T[:3, :3].T - T[:3, 3]), 1) * term.inv_sigma
    assert np.allclose(e[:, 0], expected, rtol=1e-12, atol=1e-9)
    fixed_normal = lambda X: np.sum(n * (planes.target_cam - planes.base_points @ X[:3, :3].T - X[:3, 3]), 1) \
        * term.inv_sigma
    for k in range(6):
        x = np.zeros(6)
        x[k] = 1e-6
        numeric = (fixed_normal(_step(T, x)) - fixed_normal(_step(T, -x))) / 2e-6
        assert np.allclose(numeric, J[:, 0, k], rtol=1e-5, atol=1e-3)


def test_compiled_passes_are_the_normal_equations_of_the_rows():
    """PlaneTerm's and SilhouetteTerm's one-pass normal equations and costs (the Jacobian never stored) are those
    that Term forms from their residuals and Jacobians, bit for bit."""
    rng = np.random.default_rng(5)
    planes = PlaneTerms(rng.normal(0, 0.05, (500, 3)), rng.normal(size=(500, 3)),
                        rng.normal(0, 0.05, (500, 3)) + [0, 0, 1])
    box = SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05)))
    T = make_T(Rotation.from_euler("xyz", [0.3, -0.2, 0.2]).as_matrix(), [0.01, -0.005, 0.5])
    closer = K @ np.diag([1.1, 1.1, 1.0])
    views = [mask_view(box.render(T, K, (240, 320)), K), mask_view(box.render(T, closer, (240, 320)), closer)]
    P = box.contour(T, K, (240, 320))
    assert len(P) > 100
    contours = SilhouetteTerm(np.concatenate([P, P]), np.repeat([1, 0], len(P)), views, np.array([1.5, 0.7]))
    moved = _step(T, np.array([0.01, -0.02, 0.01, 0.002, -0.001, 0.003]))
    for term in (PlaneTerm(planes, rng.uniform(0.001, 0.003, 500)), contours):
        H, g, H_rows, g_rows = np.zeros((6, 6)), np.zeros(6), np.zeros((6, 6)), np.zeros(6)
        cost = term.normal_equations(moved, H, g)
        cost_rows = Term.normal_equations(term, moved, H_rows, g_rows)
        assert np.array_equal(H, H_rows) and np.array_equal(g, g_rows) and np.abs(g).sum() > 0
        assert cost == cost_rows == term.cost(moved)
        assert len(term) == len(term.residuals(moved, False)[0])


def test_plane_solve_is_the_optimisers_solve():
    """PlaneTerm.solve, optimize's loop compiled for point-to-plane rows alone, lands where optimize does (its
    damping and stops taken over; the sums differ in order only), from starts a few centimetres and degrees off a
    noisy scene with a fifth of its points astray, and leaves a pose with no rows where it is."""
    rng = np.random.default_rng(11)
    for _ in range(10):
        n = int(rng.integers(20, 2000))
        normals = rng.normal(size=(n, 3))
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        points = rng.normal(0, 0.3, (n, 3))
        T_true = make_T(Rotation.from_rotvec(rng.normal(0, 0.2, 3)).as_matrix(), rng.normal(0, 0.1, 3) + [0, 0, 1.5])
        target = transform_points(T_true, points) + rng.normal(0, 0.003, (n, 3))
        target[: n // 5] += rng.normal(0, 0.1, (n // 5, 3))
        T_start = make_T(Rotation.from_rotvec(rng.normal(0, 0.05, 3)).as_matrix() @ T_true[:3, :3],
                         T_true[:3, 3] + rng.normal(0, 0.03, 3))
        term = PlaneTerm(PlaneTerms(points, normals, target), 0.005)
        T_solved = term.solve(T_start, max_iterations=10)
        assert np.allclose(T_solved, optimize(T_start, stack([]), OptimizeOptions(max_iterations=10), [term])[0],
                           rtol=0, atol=1e-12)
        assert np.linalg.norm(T_solved[:3, 3] - T_start[:3, 3]) > 1e-3
    empty = PlaneTerm(PlaneTerms(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))), 0.005)
    assert np.array_equal(empty.solve(T_start, max_iterations=10), T_start)


def test_pairs_kept_from_another_calibration_are_the_pairs_made_again():
    """associate_again along a calibration that drifts a little each step (as from key frame to key frame) and
    with the gate shrinking and growing: the same pairs as associating afresh every time, points 3 cm off the
    surface (beyond the gate) included; at a calibration that did not move, the kept pairing is taken whole, and
    for another model not at all."""
    rng = np.random.default_rng(7)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    points, faces = trimesh.sample.sample_surface_even(mesh, 2000, seed=0)
    model = SurfaceModel(np.asarray(points), mesh.face_normals[faces])
    T_base_model = make_T(Rotation.from_euler("xyz", [0.2, 0.1, -0.3]).as_matrix(), [0.3, 0.0, 0.4])
    T_cam_base = make_T(Rotation.from_euler("xyz", [2.5, 0.2, -0.4]).as_matrix(), [0.05, -0.02, 0.9])
    seen = np.asarray(trimesh.sample.sample_surface(mesh, 3000, seed=1)[0]) * rng.uniform(0.97, 1.03, (3000, 1))
    seen[:300] *= 1.3
    frame = (T_base_model, transform_points(T_cam_base @ T_base_model, seen))
    kept, T, taken = None, T_cam_base, 0
    for i, gate in enumerate([0.1, 0.05, 0.02, 0.01, 0.03] * 4):
        T = make_T(Rotation.from_rotvec(rng.normal(0, 0.002, 3)).as_matrix(), rng.normal(0, 0.001, 3)) @ T
        fresh = associate(T, [frame], model, gate)
        again, kept = associate_again(T, frame, model, gate, kept)
        for name in ("base_points", "base_normals", "target_cam"):
            assert np.array_equal(getattr(fresh, name), getattr(again, name)), (i, gate, name)
        taken += len(fresh.target_cam)
    assert 0 < taken < 20 * 3000
    planes, same = associate_again(T, frame, model, 0.03, kept)
    assert same is kept and np.array_equal(planes.target_cam, associate(T, [frame], model, 0.03).target_cam)
    larger = SurfaceModel(model.points * 1.02, model.normals)  # a pairing belongs to its model: not taken for another
    planes, _ = associate_again(T, frame, larger, 0.03, kept)
    assert np.array_equal(planes.base_points, associate(T, [frame], larger, 0.03).base_points)


def test_depth_agreement_tells_the_right_calibration_from_a_turned_one():
    """An L-shaped part seen in two key frames: its depth agrees with the true calibration (points sampled
    apart from the model's, so distances are not zero), much less with one turned 90 degrees about the part's
    centre or moved 2 cm; a larger noise scale forgives more; no depth points give NaN. The noise scale
    measured at the truth (its distances are sampling gaps, well below sigma) is below 1, at a wrong pose above."""
    mesh = trimesh.util.concatenate([trimesh.creation.box([0.08, 0.02, 0.02]),
                                     trimesh.creation.box([0.02, 0.05, 0.02]).apply_translation([0.03, 0.035, 0])])
    points, faces = trimesh.sample.sample_surface_even(mesh, 3000, seed=0)
    model = SurfaceModel(np.asarray(points), mesh.face_normals[faces])
    seen = trimesh.sample.sample_surface_even(mesh, 500, seed=1)[0]
    T_cam_base = make_T(Rotation.from_euler("xyz", [2.5, 0.2, -0.4]).as_matrix(), [0.05, -0.02, 0.9])
    T_base_ee = [make_T(Rotation.from_euler("xyz", a).as_matrix(), t)
                 for a, t in (([0, 0, 0], [0.3, 0, 0.4]), ([0.3, -0.5, 1.0], [0.35, 0.1, 0.35]))]
    frames = [(T, transform_points(T_cam_base @ T, seen)) for T in T_base_ee]
    centre = T_cam_base @ T_base_ee[0] @ make_T(np.eye(3), mesh.centroid)
    turned = centre @ make_T(Rotation.from_euler("y", 90, degrees=True).as_matrix(), [0, 0, 0]) @ inv_T(centre) \
        @ T_cam_base
    moved = make_T(np.eye(3), [0.02, 0, 0]) @ T_cam_base
    right, off, away = (depth_distances(T, frames, model, 0.002, 0.0036) for T in (T_cam_base, turned, moved))
    assert robust_scale(right) < 0.5 < 1.0 < robust_scale(off)
    assert depth_agreement(right, 1.0) > 0.9  # the sampling floor: about 1 mm to the nearest of 3000 points
    assert depth_agreement(off, 1.0) < 0.5 * depth_agreement(right, 1.0)
    assert depth_agreement(away, 1.0) < 0.5 * depth_agreement(right, 1.0)
    assert depth_agreement(off, 0.25) < depth_agreement(off, 1.0) < depth_agreement(off, 4.0)
    empty = depth_distances(T_cam_base, [(T_base_ee[0], np.zeros((0, 3)))], model, 0.002, 0.0036)
    assert len(empty) == 0 and np.isnan(depth_agreement(empty, 1.0)) and robust_scale(empty) == 1.0


def _cylinder_depth(z_axis, radius, f=229.0, shape=(240, 320)):
    """Depth (along the optical axis) of an upright cylinder whose axis crosses the optical axis at z_axis."""
    u = np.arange(shape[1]) - (shape[1] - 1) / 2
    x = np.tile(u / f, (shape[0], 1))
    a = 1 + x ** 2
    disc = z_axis ** 2 - a * (z_axis ** 2 - radius ** 2)
    return np.where(disc > 0, (z_axis - np.sqrt(np.maximum(disc, 0))) / a, 0.0)


def test_a_window_matcher_reads_a_rounded_surface_farther_and_a_plane_where_it_lies():
    """The window bias at a cylinder's front is the closed form z^2 s^2 / (2 r f^2) (a 4 cm link at 1 m:
    about half a millimetre at s = 1.5 px), grows with the window's area, and is nil on a slanted plane, whose
    inverse depth is linear in the image."""
    f = 229.0
    for z_axis, r in ((1.04, 0.04), (0.62, 0.02)):
        z = _cylinder_depth(z_axis, r, f)
        centre = window_bias(z, z > 0, 1.5)[120, 159:161].mean()
        assert centre == pytest.approx((z_axis - r) ** 2 * 1.5 ** 2 / (2 * r * f ** 2), rel=0.05)
        wide, narrow = (window_bias(z, z > 0, s)[120, 159:161].mean() for s in (2.0, 1.0))
        assert wide / narrow == pytest.approx(4.0, rel=0.1)
    v, u = np.mgrid[0:240, 0:320]
    plane = 1.0 / (0.8 + 0.0015 * (u - 160) - 0.0008 * (v - 120))  # 1/z linear: a plane seen in perspective
    inner = (slice(10, -10), slice(10, -10))
    assert np.abs(window_bias(plane, plane > 0, 1.5)[inner]).max() < 2e-6  # float32 sums


def test_depth_less_its_window_bias_is_the_surface_and_a_straddling_window_says_nothing():
    """A matcher simulated as the window's mean inverse depth over a cylinder: less the bias, the surface it
    reads; where the drawn model holds a bar before a wall, the windows across the step have no depth left."""
    z = _cylinder_depth(1.04, 0.04)
    drawn = z > 0
    sensed = z + window_bias(z, drawn, 1.5)
    read = without_window_bias(sensed, z, drawn, 1.5)
    kept = read > 0  # all but the rim, where the window reaches past the outline
    assert kept.sum() > 0.8 * drawn.sum() and np.abs(read - z)[kept].max() < 1e-9
    wall = np.full((240, 320), 1.5)
    bar = np.where(np.abs(np.arange(320) - 160) < 12, 0.8, 0.0)[None].repeat(240, 0)
    scene = np.where(bar > 0, bar, wall)
    read = without_window_bias(scene, scene, scene > 0, 1.5)
    assert np.all(read[:, 100] == 1.5) and np.all(read[:, 160] == pytest.approx(0.8))
    step = np.abs(window_bias(scene, scene > 0, 1.5)) > WINDOW_BIAS_MAX_M
    assert step[:, 147:149].all() and np.all(read[step] == 0)


def test_each_frame_may_bring_its_own_model_placed_in_the_base_frame():
    """With no mask the depth term matches each frame's cloud to the robot placed by that frame's joint
    states: a list of models, one per frame, already in the base frame. It pairs and measures exactly as one
    shared model at each frame's pose does; a frame without points is skipped with its model."""
    mesh = trimesh.creation.box([0.08, 0.03, 0.05])
    points, faces = trimesh.sample.sample_surface_even(mesh, 2000, seed=0)
    model = SurfaceModel(np.asarray(points), mesh.face_normals[faces])
    T_cam_base = make_T(Rotation.from_euler("xyz", [2.5, 0.2, -0.4]).as_matrix(), [0.05, -0.02, 0.9])
    T_base = [make_T(Rotation.from_euler("xyz", a).as_matrix(), t)
              for a, t in (([0, 0, 0], [0.3, 0, 0.4]), ([0.3, -0.5, 1.0], [0.35, 0.1, 0.35]), ([0, 0, 0], [0, 0, 0]))]
    seen = trimesh.sample.sample_surface_even(mesh, 300, seed=1)[0]
    clouds = [transform_points(T_cam_base @ T, seen) for T in T_base[:2]] + [np.zeros((0, 3))]
    placed_models = [SurfaceModel(transform_points(T, model.points), model.normals @ T[:3, :3].T) for T in T_base]
    T_off = make_T(np.eye(3), [0.004, -0.002, 0.003]) @ T_cam_base
    shared = associate(T_off, list(zip(T_base, clouds)), model, 0.02)
    own = associate(T_off, [(np.eye(4), c) for c in clouds], placed_models, 0.02)
    for a, b in ((shared.base_points, own.base_points), (shared.base_normals, own.base_normals),
                 (shared.target_cam, own.target_cam)):
        assert len(a) > 500 and np.allclose(a, b, atol=1e-9)
    assert np.allclose(depth_distances(T_off, list(zip(T_base, clouds)), model, 0.002, 0.0036),
                       depth_distances(T_off, [(np.eye(4), c) for c in clouds], placed_models, 0.002, 0.0036))


def test_robust_sigma_is_the_scaled_median_absolute_residual():
    """The one robust scale of the depth term (icp.robust_scale) and of each mask (contour_term's spread), as
    both wrote it: 1.4826 x the median |residual|."""
    r = np.array([-3.0, 1.0, 2.0, -0.5, 10.0])
    assert robust_sigma(r) == 1.4826 * 2.0 == robust_scale(r)
    assert robust_scale(r / 100) == 0.25  # at least min_scale


class _Misled(Term):
    """A residual whose Jacobian points the wrong way, as a sampled field's can at the optimum: every step
    the model promises raises the cost. Counts its evaluations."""

    def __init__(self):
        self.evaluations = 0

    def residuals(self, T, jacobian):
        self.evaluations += 1
        J = np.zeros((1, 1, 6))
        J[0, 0, 4] = -1 / 1e-3
        return np.array([[(T[1, 3] - 0.0003) / 1e-3]]), (J if jacobian else None)


def test_optimisation_stops_raising_the_damping_once_steps_stop_mattering():
    """min_step: a solve whose trials all fail ends once the damped step moves the pose less than 1 um,
    not after damping 1e8; the pose is the same (no step was taken either way)."""
    runs = {}
    for min_step in (0.0, 1e-6):
        term = _Misled()
        T, _ = optimize(np.eye(4), stack([]), OptimizeOptions(min_step=min_step), [term])
        runs[min_step] = T, term.evaluations
    assert np.array_equal(runs[0.0][0], np.eye(4)) and np.array_equal(runs[1e-6][0], np.eye(4))
    assert runs[1e-6][1] < runs[0.0][1]  # 9 evaluations against 15


class _Unobservable(Term):
    """Residuals at a silhouette term's scale (thousands of rows, large Jacobians) that turning about x and
    moving along x change alike: the pose's sixth direction (one turned against the other) moves none of them."""

    def __init__(self, n=2000):
        rng = np.random.default_rng(0)
        rows = rng.normal(size=(n, 5)) * 3000.0
        self.J = np.c_[rows[:, :3], rows[:, 0], rows[:, 3:]][:, None, :]
        self.target = np.array([0.001, -0.002, 0.001, 0.001, 0.002, -0.001])

    def residuals(self, T, jacobian):
        x = np.r_[Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3] - [0.0, 0.1, 0.5]]
        return (self.J[:, 0] @ (x - self.target))[:, None], (self.J if jacobian else None)


def test_a_direction_no_residual_moves_does_not_stop_the_solve():
    """With min_decrease the solver predicts the Gauss-Newton step's decrease; where H is singular to the
    machine's precision (as on hard-case seed 23's UR10e + 2F-85, its end-effector out of view: condition
    1.7e17, numpy's "Singular matrix" stopped the run) that is the step of least norm, not an error."""
    term = _Unobservable()
    T0 = make_T(t=[0.0, 0.1, 0.5])
    cost = lambda T: float(np.log1p(term.residuals(T, False)[0] ** 2).sum())
    T, _ = optimize(T0, stack([]), OptimizeOptions(min_decrease=1e-6, max_iterations=20), [term])
    assert np.isfinite(T).all() and cost(T) < 0.01 * cost(T0)


def test_memory_pool_threshold_and_farthest_point_key_frames():
    pool = MemoryPool(threshold_deg=10.0)
    rot = lambda deg: make_T(Rotation.from_euler("z", deg, degrees=True).as_matrix())
    found = type("F", (), {"candidates": [object()], "K": K})()
    empty = type("F", (), {"candidates": [], "K": K})()
    added = [pool.consider(MemoryEntry(i, rot(a), found)) for i, a in enumerate([0, 5, 12, 20, 40, 90, 91])]
    assert added == [True, False, True, False, True, True, False]  # 20 is 8 deg from 12
    assert not pool.consider(MemoryEntry(9, rot(150), empty))
    keys = pool.key_frames(rot(0)[:3, :3], 2)
    assert [e.frame for e in keys] == [5, 4]  # 90 deg first, then the one farthest from {0 (seed), 90}: 40
    assert [e.frame for e in pool.key_frames(rot(-60)[:3, :3], 1)] == [5]  # 150 deg away


def test_memory_pool_admits_a_moved_end_effector_when_asked():
    """The refinement's rule: a frame 5 deg from a pooled one joins when the end-effector moved more than
    threshold_m; the paper's rule (no threshold_m) looks at orientation alone."""
    found = type("F", (), {"candidates": [object()], "K": K})()
    at = lambda deg, x: make_T(Rotation.from_euler("z", deg, degrees=True).as_matrix(), [x, 0.0, 0.0])
    poses = [at(0, 0.0), at(5, 0.004), at(5, 0.03), at(3, 0.031)]
    paper, moved = MemoryPool(threshold_deg=10.0), MemoryPool(threshold_deg=10.0, threshold_m=0.005)
    assert [paper.consider(MemoryEntry(i, T, found)) for i, T in enumerate(poses)] == [True, False, False, False]
    assert [moved.consider(MemoryEntry(i, T, found)) for i, T in enumerate(poses)] == [True, False, True, False]


def test_consensus_picks_the_symmetry_mode_that_agrees_with_kinematics():
    rng = np.random.default_rng(4)
    T_cam_base = _pose(rng, 1.0)
    flip = make_T(Rotation.from_euler("z", 180, degrees=True).as_matrix())
    frames = []
    for i in range(5):
        T_base_ee = make_T(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.2, 0.2, 3))
        true = T_cam_base @ T_base_ee
        jitter = make_T(Rotation.from_rotvec(rng.normal(0, 0.03, 3)).as_matrix())
        cands = [Candidate(0, true @ jitter, np.zeros((30, 2)), np.zeros((30, 3)), np.zeros((30, 3)), 1.0)]
        # every frame also has a symmetric twin; frame 0's twin has more inliers than its true pose
        n = 60 if i == 0 else 20
        cands.append(Candidate(0, true @ flip, np.zeros((n, 2)), np.zeros((n, 3)), np.zeros((n, 3)), 1.0))
        # and a wrong view 90 deg off, no symmetry image: the vote drops it as well (an outlier filter too)
        wrong = true @ make_T(Rotation.from_euler("x", 90, degrees=True).as_matrix())
        cands.append(Candidate(0, wrong, np.zeros((10, 2)), np.zeros((10, 3)), np.zeros((10, 3)), 1.0))
        frames.append((T_base_ee, cands))
    keep, T = consensus(frames, tolerance_deg=20.0)
    assert all(k == [True, False, False] for k in keep)
    assert np.rad2deg(rotation_angle(T[:3, :3], T_cam_base[:3, :3])) < 5
