"""Silhouette refinement (our extension): the contour lies on the mask boundary at the true pose, the
contour term's Jacobian is its derivative, the refinement pulls a perturbed calibration back on
rendered frames, and the paper's variants keep their identity."""

import cv2
import numpy as np
import pytest
import trimesh

from feepe.backbones import DEFAULT, get_backbone
from feepe.estimator import Estimator, FeepeOptions, RobotView, describe
from feepe.icp import SurfaceModel
from feepe.onboarding import onboard
from feepe.optimize import _step
from feepe.silhouette import (KEPT, REUSE_PX, PartsSilhouette, SilhouetteModel, SilhouetteTerm, contour_term,
                              frame_iou, iou_bound, mask_view, mean_iou, placed, visible_contour)
from kernel.bop import read_frame, read_scene, split_dir
from kernel.errors import UserError
from kernel.template_set import find_template_set
from kernel.transforms import inv_T, make_T, transform_points

K = np.array([[300.0, 0, 80], [0, 300.0, 60], [0, 0, 1]])


def sample(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an (H, W) image at sub-pixel (u, v), clamped to the image."""
    h, w = img.shape
    u, v = np.clip(uv[:, 0], 0, w - 1.001), np.clip(uv[:, 1], 0, h - 1.001)
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    a, b = u - u0, v - v0
    return ((1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u0 + 1]
            + (1 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])


def _box_pose():
    T = np.eye(4)
    T[:3, :3] = trimesh.transformations.euler_matrix(0.3, -0.4, 0.2)[:3, :3]
    T[:3, 3] = [0.01, -0.005, 0.5]
    return T


def test_box_contour_lies_on_its_rendered_mask_boundary():
    model = SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05)))
    T = _box_pose()
    mask = model.render(T, K, (120, 160))
    P = model.contour(T, K, mask.shape)
    uv = transform_points(T, P)[:, :2] / transform_points(T, P)[:, 2:] * 300 + [80, 60]
    d = sample(mask_view(mask, K).sdt, uv)
    assert len(P) > 100  # about one point per pixel of a ~60 px outline
    assert abs(np.mean(d)) < 0.1 and np.mean(np.abs(d) < 1.0) > 0.95


def test_contour_term_jacobian_matches_finite_differences():
    model = SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05)))
    T = _box_pose()
    view = mask_view(model.render(T, K, (120, 160)), K)
    T0 = _step(T, np.array([0.02, -0.01, 0.01, 0.002, 0.001, -0.003]))
    P = model.contour(T0, K, view.sdt.shape)
    term = SilhouetteTerm(P, np.zeros(len(P), int), [view], 1.0)
    e, J = term.residuals(T0, True)
    for k, h in enumerate([3e-3] * 3 + [1e-3] * 3):  # about half a pixel: the field is piecewise linear
        x = np.zeros(6)
        x[k] = h
        numeric = (term.residuals(_step(T0, x), False)[0] - term.residuals(_step(T0, -x), False)[0]) / (2 * h)
        big = np.abs(J[:, 0, k]) > 0.1
        assert np.corrcoef(numeric[:, 0], J[:, 0, k])[0, 1] > 0.85  # box corners break the field's smoothness
        assert abs(np.median(numeric[big, 0] / J[big, 0, k]) - 1.0) < 0.05


def test_image_motion_bound_covers_every_vertex():
    model = SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05)))
    T = _box_pose()
    V = model.mesh.vertices
    rng = np.random.default_rng(0)
    for _ in range(20):
        T2 = _step(T, np.concatenate([rng.normal(0, 0.01, 3), rng.normal(0, 0.002, 3)]))
        moved = np.linalg.norm(_project(transform_points(T2, V)) - _project(transform_points(T, V)), axis=1).max()
        bound = PartsSilhouette([model]).motion_px(T[None], T2[None], K)
        assert moved <= bound <= 4 * moved + 0.5


def test_image_span_bound_covers_the_rendered_mask_and_shrinks_with_distance():
    boxes = [SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05))), SilhouetteModel(trimesh.creation.box((0.02,) * 3))]
    parts, T = PartsSilhouette(boxes), _box_pose()
    placed = np.stack([T, T @ make_T(t=[0.1, 0.0, 0.0])])
    v, u = np.nonzero(parts.render_depth(placed, K, (120, 160)) > 0)
    span = parts.span_px(placed, K)
    assert max(np.ptp(u), np.ptp(v)) <= span <= 3 * max(np.ptp(u), np.ptp(v))
    away = np.stack([make_T(t=[0.0, 0.0, 9.0]) @ X for X in placed])  # the camera 9 m farther back
    assert parts.span_px(away, K) < span / 5
    assert parts.span_px(np.stack([make_T(t=[0.0, 0.0, -T[2, 3]]) @ X for X in placed]), K) == np.inf  # at the camera


def test_a_frames_contour_is_reused_until_the_model_moves_half_a_pixel():
    box = SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05)))
    model, T = PartsSilhouette([box]), _box_pose()
    view = mask_view(box.render(T, K, (120, 160)), K)
    first = visible_contour(model, T[None], view, 1.0)
    near = _step(T, np.array([0, 0, 0, 0.1 * REUSE_PX * 0.5 / 300, 0, 0]))
    assert visible_contour(model, near[None], view, 1.0) is first
    far = _step(T, np.array([0.05, 0, 0, 0, 0, 0]))
    again = visible_contour(model, far[None], view, 1.0)
    assert again is not first and len(again[0]) and np.array_equal(view.contours[model, 1.0][0][0], far[None])
    assert visible_contour(model, T[None], view, 1.0) is first  # the earlier pose is kept too
    for k in range(KEPT):  # until KEPT newer poses push it out
        visible_contour(model, _step(T, np.array([0.05 * (k + 2), 0, 0, 0, 0, 0]))[None], view, 1.0)
    assert visible_contour(model, T[None], view, 1.0) is not first


def test_measured_scale_follows_how_well_each_frames_mask_fits():
    """Beside depth, an exactly fitting mask keeps the floor scale and a mask whose outline is 3 px off
    (a segmenter's error) gets 1.4826 x its median distance, about 4.4 px: each frame its own, in one term."""
    box = SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05)))
    model, T = PartsSilhouette([box]), _box_pose()
    exact = box.render(T, K, (120, 160))
    grown = cv2.dilate(exact.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))) > 0
    frames = [(np.eye(4)[None], mask_view(exact, K)), (np.eye(4)[None], mask_view(grown, K))]
    fine, off = contour_term(model, T, frames, 0.25, measured=True).sigma_px
    assert fine < 0.6 and 3.5 < off < 5.0
    assert list(contour_term(model, T, frames, 0.25).sigma_px) == [0.25, 0.25]


def _project(P):
    return P[:, :2] / P[:, 2:] * 300 + [80, 60]


def test_an_occluder_in_front_is_not_taken_for_the_outline():
    """A bar 10 cm in front hides the box's left third: with the frame's depth, the true pose still scores
    IoU ~1 and no contour point is kept under the bar; without depth, the cut outline looks like a misfit."""
    box = SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05)))
    model, T = PartsSilhouette([box]), _box_pose()
    depth = box.render_depth(T, K, (120, 160))
    assert abs(np.median(depth[depth > 0]) - 0.5) < 0.03
    cols = np.nonzero(depth.any(0))[0]
    bar = np.zeros_like(depth, bool)
    bar[:, : cols[0] + (cols[-1] - cols[0]) // 3] = True
    visible = (depth > 0) & ~bar
    depth = np.where(bar, 0.4, depth)
    frames = [(np.eye(4)[None], mask_view(visible, K, depth))]
    assert mean_iou(model, T, frames) > 0.99
    assert mean_iou(model, T, [(np.eye(4)[None], mask_view(visible, K))]) < 0.8
    term = contour_term(model, T, frames, 1.0)
    uv = transform_points(T, term.base_points)[:, :2] / transform_points(T, term.base_points)[:, 2:] * 300 + [80, 60]
    assert len(uv) > 50 and not bar[np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)].any()


def test_paper_variants_keep_their_identity_and_options_are_checked():
    net = get_backbone(DEFAULT)
    assert not any(k.startswith("silhouette") or k == "refine" for k in describe(FeepeOptions(), net))
    assert describe(FeepeOptions(refine="silhouette"), net)["refine"] == "silhouette"
    with pytest.raises(UserError, match="refinement 'edges' unknown"):
        FeepeOptions(refine="edges")
    with pytest.raises(UserError, match="variant A is PnP only"):
        FeepeOptions(variant="A", refine="silhouette")
    with pytest.raises(UserError, match="silhouette 'arm' unknown"):
        FeepeOptions(refine="silhouette", silhouette="arm")
    with pytest.raises(UserError, match="needs refine silhouette"):
        FeepeOptions(silhouette="robot")
    with pytest.raises(UserError, match="refit growth -0.5 must be >= 0"):
        FeepeOptions(refine="silhouette", silhouette_refit_growth=-0.5)
    # options added later leave the identity of the runs stored before them unchanged
    ee = describe(FeepeOptions(refine="silhouette"), net)
    assert "robot_start_frames" not in ee and "silhouette_refit_growth" not in ee
    robot = describe(FeepeOptions(refine="silhouette", silhouette="robot", silhouette_refit_growth=0.25), net)
    assert robot["robot_start_frames"] == 3 and robot["silhouette_refit_growth"] == 0.25
    # refinement runs from before the rasteriser (no renderer named) are not resumed; the paper's variants are
    assert ee["silhouette_renderer"] == "zbuffer" and "silhouette_renderer" not in describe(FeepeOptions(), net)
    # and runs with depth from before its choice among descents heard depth; those without depth are
    assert "silhouette_choice" not in ee
    assert describe(FeepeOptions(refine="silhouette+depth"), net)["silhouette_choice"] == "iou x scaled depth agreement"


@pytest.mark.parametrize("refine", ["silhouette", "silhouette+depth"])
def test_refinement_pulls_a_wrong_calibration_onto_the_masks(tiny_dataset, refine):
    """Tiny renders (160x120: the gripper spans ~20 px, one pixel ~6 mm), the calibration started about
    2 cm and 2.5 deg off through the warm start: the refinement at least halves the end-effector error."""
    scene = next(s for s in sorted(split_dir(tiny_dataset).iterdir()) if read_scene(s)[0].end_effector == "robotiq_2f85")
    meta, ids = read_scene(scene)
    frames = [read_frame(scene, i) for i in ids]
    ply = tiny_dataset / "models" / f"obj_{meta.obj_id:06d}.ply"
    net = get_backbone(DEFAULT)
    bank = onboard(find_template_set(tiny_dataset / "templates", meta.end_effector, None), net)
    est = Estimator(bank, net, FeepeOptions(refine=refine), SurfaceModel.from_ply(ply), SilhouetteModel.from_ply(ply))
    est.T_cam_base = _step(meta.T_cam_base, np.array([0.03, -0.03, 0.02, 0.015, -0.01, 0.01]))
    start = [np.linalg.norm((est.T_cam_base @ f.T_base_ee)[:3, 3] - f.T_cam_ee[:3, 3]) for f in frames]
    errors = []
    for f in frames:
        r = est.step(f.rgb, f.depth, f.mask_visib, f.K, f.T_base_ee)
        errors.append(np.linalg.norm(r.T_cam_ee[:3, 3] - f.T_cam_ee[:3, 3]))
    assert np.median(errors) < 0.5 * np.median(start), (errors, start)


def test_robot_silhouette_pulls_a_wrong_calibration_onto_the_robot_mask(tiny_dataset):
    """The same start as above, fitted to the whole robot's mask (arm links by FK from the URDF): the
    calibration comes within 1 cm and 1 deg on every frame; without the robot view it is one clear error."""
    from eval.methods.feepe import link_mesh
    from syneepose.robots.robot import load_robot

    scene = next(s for s in sorted(split_dir(tiny_dataset).iterdir()) if read_scene(s)[0].end_effector == "robotiq_2f85")
    meta, ids = read_scene(scene)
    robot = load_robot(f"{meta.arm}+{meta.end_effector}")
    ply = tiny_dataset / "models" / f"obj_{meta.obj_id:06d}.ply"
    net = get_backbone(DEFAULT)
    bank = onboard(find_template_set(tiny_dataset / "templates", meta.end_effector, None), net)
    est = Estimator(bank, net, FeepeOptions(refine="silhouette", silhouette="robot"), None, SilhouetteModel.from_ply(ply))
    f = read_frame(scene, ids[0])
    with pytest.raises(UserError, match="needs the arm's link meshes"):
        est.step(f.rgb, f.depth, f.mask_visib, f.K, f.T_base_ee)
    est.reset(arm=[SilhouetteModel(link_mesh(robot, name)) for name in meta.links[:-1]])
    with pytest.raises(UserError, match="needs each frame's robot view"):
        est.step(f.rgb, f.depth, f.mask_visib, f.K, f.T_base_ee)
    est.T_cam_base = _step(meta.T_cam_base, np.array([0.03, -0.03, 0.02, 0.015, -0.01, 0.01]))
    for i in ids:
        f = read_frame(scene, i)
        T_base_link = robot.T_base_link(f.joint_positions)
        view = RobotView(f.link_ids > 0, np.stack([T_base_link[name] for name in meta.links[:-1]]))
        r = est.step(f.rgb, f.depth, f.mask_visib, f.K, f.T_base_ee, view)
        dT = inv_T(meta.T_cam_base) @ r.T_cam_base
        angle = np.degrees(np.arccos(np.clip((np.trace(dT[:3, :3]) - 1) / 2, -1, 1)))
        assert np.linalg.norm(dT[:3, 3]) < 0.01 and angle < 1.0, (i, dT[:3, 3], angle)


@pytest.mark.parametrize("refine", ["none", "silhouette"])
def test_arm_links_without_the_robot_outline_are_one_clear_error(tiny_dataset, refine):
    """A library user who passes arm links to an Estimator that does not fit the robot's outline (no refinement,
    or the end-effector's outline) is told what to build, not handed an AttributeError."""
    scene = sorted(split_dir(tiny_dataset).iterdir())[0]
    meta, _ = read_scene(scene)
    ply = tiny_dataset / "models" / f"obj_{meta.obj_id:06d}.ply"
    net = get_backbone(DEFAULT)
    bank = onboard(find_template_set(tiny_dataset / "templates", meta.end_effector, None), net)
    est = Estimator(bank, net, FeepeOptions(refine=refine), None,
                    SilhouetteModel.from_ply(ply) if refine != "none" else None)
    with pytest.raises(UserError, match=r"silhouette='robot'"):
        est.reset(arm=[SilhouetteModel(trimesh.creation.box((0.1, 0.1, 0.1)))])


def test_robot_parts_fit_the_outline_of_their_union():
    """Two boxes, one half in front of the other (an arm link and a gripper): each part keeps only the
    contour points on the union's outline - none where the other part covers or borders it - and the
    true pose fits the union mask while the end-effector alone would not explain it."""
    ee, link = SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05))), SilhouetteModel(trimesh.creation.box((0.15, 0.03, 0.03)))
    model, T = PartsSilhouette([ee, link]), _box_pose()
    T_link = T.copy()
    T_link[:3, 3] += [0.06, 0.01, 0.03]  # behind and to the right, overlapping in the image
    T_parts = np.stack([T, T_link])
    union = model.render_depth(T_parts, K, (120, 160)) > 0
    alone = ee.render(T, K, union.shape)
    assert union.sum() > 1.5 * alone.sum()
    view = mask_view(union, K)
    for part, T_part, P in zip(model.parts, T_parts, visible_contour(model, T_parts, view, 1.0)):
        uv = _project(transform_points(T_part, P))
        d = sample(view.sdt, uv)
        assert len(P) > 30 and np.mean(np.abs(d) < 1.0) > 0.95
        assert len(P) < 0.9 * len(part.contour(T_part, K, union.shape))  # the shared border is dropped
    frames = [(T_parts, view)]  # the camera is the base frame here
    assert mean_iou(model, np.eye(4), frames) > 0.99
    assert mean_iou(PartsSilhouette([ee]), np.eye(4), [(T_parts[:1], view)]) < 0.7


def test_render_parts_gives_each_pixel_the_nearest_part_as_drawing_each_alone():
    """The segmentation's one z-buffer: each pixel's depth and part are those of the nearest part's own render,
    the first part where two reach the same depth (a box drawn twice at one place), -1 off every part."""
    ee, link = SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05))), SilhouetteModel(trimesh.creation.box((0.15, 0.03, 0.03)))
    T = _box_pose()
    T_link = T.copy()
    T_link[:3, 3] += [0.06, 0.01, 0.03]
    model, T_parts = PartsSilhouette([link, ee, link]), np.stack([T_link, T, T_link])
    depth, part = model.render_parts(T_parts, K, (120, 160))
    alone = np.stack([m.render_depth(Tp, K, (120, 160)) for m, Tp in zip(model.parts, T_parts)])
    drawn = (alone > 0).any(0)
    nearest = np.argmin(np.where(alone > 0, alone, np.inf), 0)
    assert (part == np.where(drawn, nearest, -1)).all()
    assert (depth == np.where(drawn, np.min(np.where(alone > 0, alone, np.inf), 0), 0.0)).all()
    assert {0, 1} <= set(np.unique(part)) and 2 not in part  # the link drawn again loses its ties


def test_iou_bound_is_never_below_the_rendered_iou():
    """The screening of starts skips a render where the bound is under the bar: it must hold for every pose,
    one part or two, the model seen whole or partly off the image, and reach 1 where the pose is right."""
    ee = SilhouetteModel(trimesh.creation.box((0.06, 0.04, 0.05)))
    link = SilhouetteModel(trimesh.creation.box((0.15, 0.03, 0.03)))
    model, T = PartsSilhouette([ee, link]), _box_pose()
    T_link = T.copy()
    T_link[:3, 3] += [0.06, 0.01, 0.03]
    T_parts = np.stack([T, T_link])
    view = mask_view(model.render_depth(T_parts, K, (120, 160)) > 0, K)
    rng = np.random.default_rng(0)
    bounds = []
    for k in range(40):
        move = np.concatenate([rng.normal(0, 0.3, 3), rng.normal(0, 0.08, 3)])
        T_cam_base = np.eye(4) if k == 0 else _step(np.eye(4), move)
        for stride in (1, 2):
            rendered = frame_iou(model, placed(T_cam_base, T_parts), view, stride)
            bounds.append(iou_bound(model, placed(T_cam_base, T_parts), view, stride))
            assert rendered <= bounds[-1] + 1e-12
    assert bounds[0] == 1.0 and min(bounds) < 0.5  # the bound does pass over starts far off


def test_a_part_reaching_behind_the_camera_keeps_only_its_edges_in_front():
    """An arm link can pass the camera plane: its edges behind it project nowhere and are left out (the
    rest may still outline the robot) instead of being sampled along a projection that grows without bound."""
    bar = SilhouetteModel(trimesh.creation.box((0.04, 0.04, 2.0)))
    T = np.eye(4)
    T[:3, 3] = [0.05, 0.0, 0.3]  # from 0.7 m behind the camera to 1.3 m in front
    P = bar.contour(T, K, (120, 160))
    assert 0 < len(P) < 2000 and (transform_points(T, P)[:, 2] > 0.05).all()
