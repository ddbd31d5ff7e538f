"""Pure sampling code: seeded, within ranges, geometry conventions."""

import dataclasses
import json

import numpy as np
import pytest

from kernel.bop import Frame, SceneMeta, SceneWriter, read_scene
from kernel.errors import UserError
from kernel.transforms import fibonacci_sphere, inv_T, transform_points
from syneepose.jobs import SceneContent, SegmentSelection, make_jobs, parse_shard
from syneepose.preset import load_preset, parse_preset
from syneepose.scene.motion import min_jerk, trajectory
from syneepose.scene.sample import distractors, kelvin_to_rgb, look_at, rng_for
from syneepose.scene.spec import RenderSettings
from syneepose.templates import poses


def test_look_at_points_the_optical_axis():
    T = look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(T[:3, 2], -np.array([1, 2, 3]) / np.linalg.norm([1, 2, 3]))
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    assert T[2, 1] < 0  # image y (down) points away from the world up


def test_min_jerk_and_trajectory_limits():
    s = np.linspace(0, 1, 101)
    assert min_jerk(s)[0] == 0 and min_jerk(s)[-1] == pytest.approx(1)
    assert (np.diff(min_jerk(s)) >= 0).all()
    limits = [(-1.0, 1.0), (0.0, 0.5)]
    q = trajectory(np.random.default_rng(0), [0.0, 0.25], limits, 50, 4, 2.0)
    assert q.shape == (50, 2)
    assert (q[:, 0] >= -1).all() and (q[:, 0] <= 1).all() and (q[:, 1] >= 0).all() and (q[:, 1] <= 0.5).all()
    assert np.abs(np.diff(q, axis=0)).max() < 0.5  # smooth: no jumps between frames


def test_seeded_streams():
    a = rng_for(0, "ur5e+robotiq_2f85", 3).random(4)
    assert np.array_equal(a, rng_for(0, "ur5e+robotiq_2f85", 3).random(4))
    assert not np.array_equal(a, rng_for(1, "ur5e+robotiq_2f85", 3).random(4))
    assert not np.array_equal(a, rng_for(0, "ur5e+robotiq_2f85", 4).random(4))


def test_kelvin_colours():
    warm, cold = kelvin_to_rgb(2700), kelvin_to_rgb(7500)
    assert warm[0] == 1.0 and warm[2] < warm[1] < 1.0
    assert cold[2] == 1.0 and cold[0] < 1.0


def test_fibonacci_templates_cover_the_sphere():
    v = fibonacci_sphere(80)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0)
    assert np.abs(v.mean(0)).max() < 0.02
    p = poses(80, 12, np.zeros(3), 0.1)
    assert len(p) == 960
    for _, _, T in p[:24]:  # the model centre lies on the optical axis
        c = T[:3, 3]
        assert abs(c[0]) < 1e-9 and abs(c[1]) < 1e-9 and c[2] > 0


def test_scene_ids_are_stable_across_subsets_and_shards(tmp_path):
    content, render = SceneContent(load_preset("mini"), "mini", seed=0), RenderSettings(64, 48, 2)

    def ids(configs, shard=(0, 1)):
        plan = make_jobs(content, render, SegmentSelection(configs, 2, shard), tmp_path, tmp_path)
        return [j.scene_id for j in plan.jobs]

    full = ids(("panda+panda_hand", "ur5e+robotiq_2f85"))
    assert set(ids(("ur5e+robotiq_2f85",))) <= set(full)
    assert sorted(i for k in range(3) for i in ids(("panda+panda_hand", "ur5e+robotiq_2f85"), (k, 3))) == sorted(full)
    assert parse_shard("1/3") == (1, 3)
    with pytest.raises(UserError):
        parse_shard("3/3")


@pytest.fixture(scope="module")
def ur5e_checks(assets):
    from syneepose import paths
    from syneepose.robots.ee_models import load_ee_mesh
    from syneepose.robots.robot import load_robot
    from syneepose.scene.motion import MotionChecks

    robot = load_robot("ur5e+robotiq_2f85")
    return robot, MotionChecks(robot, load_ee_mesh(robot.ee, paths.part_urdf(robot.ee.name)))


def test_self_collision_known_poses(ur5e_checks):
    robot, checks = ur5e_checks
    home = np.array(robot.arm.home)
    folded = home.copy()
    folded[2] = 3.1  # elbow folded back: the forearm passes through the upper arm
    assert not checks.self_collision(home[None])[0]
    assert checks.self_collision(folded[None])[0]


def _planned_twice(preset, robot, checks, stream, seed, frames, width, height):
    """The segment plan, asserted to be the same when planned again with the same seed."""
    from syneepose.scene.plan import plan_segment

    spec = plan_segment(preset, robot, checks, stream, seed, frames, width, height)
    again = plan_segment(preset, robot, checks, stream, seed, frames, width, height)
    np.testing.assert_array_equal(spec.q, again.q)
    np.testing.assert_array_equal(spec.T_base_cam, again.T_base_cam)
    if spec.marker is not None:
        np.testing.assert_array_equal(spec.marker.T_ee_board, again.marker.T_ee_board)
    return spec


def _assert_arm_rules(spec, checks, preset, width, height):
    """No self-collision, above the floor, the end-effector inside the image and visible enough."""
    assert not checks.self_collision(spec.q).any()
    assert checks.above_floor(spec.q, 0.1).all()
    inside, visible = checks.check(spec.q, spec.T_base_cam, spec.K, width, height)
    assert (inside >= 0.999).all() and (visible >= preset.camera.min_visible).all()


def test_the_planners_early_verdict_is_the_full_checks(ur5e_checks):
    """`accepts` (what planning asks, stopping at the first failing frame) says what `check`'s per-frame
    figures say, for cameras it accepts and cameras it rejects, on a mask of frames as the exit case gives."""
    from syneepose.scene.sample import sample_segment

    robot, checks = ur5e_checks
    preset = load_preset("mini")
    rng = rng_for(0, robot.config, 0)
    q = trajectory(rng, robot.arm.home, robot.arm.limits, 8, 3, 0.8)
    frames = np.arange(8) % 4 != 3
    verdicts = set()
    for _ in range(40):
        spec = sample_segment(rng, preset, robot, robot.config, 0, 0, q, 64, 48, [])
        inside, visible = checks.check(q, spec.T_base_cam, spec.K, 64, 48, 0.02)
        expected = bool(np.all(inside[frames] >= 0.999) and np.all(visible[frames] >= preset.camera.min_visible))
        assert checks.accepts(q, spec.T_base_cam, spec.K, 64, 48, 0.02, preset.camera.min_visible, frames) == expected
        verdicts.add(expected)
        if len(verdicts) == 2:
            break
    assert verdicts == {True, False}


def test_planned_segment_meets_every_rule(ur5e_checks):
    robot, checks = ur5e_checks
    preset = load_preset("mini")
    spec = _planned_twice(preset, robot, checks, 5, 0, 12, 64, 48)
    _assert_arm_rules(spec, checks, preset, 64, 48)
    lo, hi = np.array(robot.arm.limits).T
    assert ((spec.q >= lo) & (spec.q <= hi)).all()


def test_stations_show_the_whole_board_face_on_and_spread_apart(ur5e_checks):
    """The fair marker peer's stations: every rule holds in every frame, and the same seed plans the same."""
    from kernel.transforms import rotation_angle
    from syneepose.scene.marker import facing

    robot, checks = ur5e_checks
    preset = load_preset("targeting-stations")
    spec = _planned_twice(preset, robot, checks, 0, 3, 8, 640, 480)
    T_cam_board = inv_T(spec.T_base_cam) @ robot.T_base_ee(spec.q) @ spec.marker.T_ee_board
    tilt = np.rad2deg(np.arccos(facing(T_cam_board, spec.marker)))
    assert (tilt <= preset.stations.max_tilt_deg + 1e-6).all()
    corners = transform_points(spec.marker.T_ee_board, spec.marker.corners())
    inside, seen = checks.seen(spec.q, spec.T_base_cam, spec.K, 640, 480, corners, ee_occludes=True)
    assert (inside == 1).all() and (seen == 1).all()
    _assert_arm_rules(spec, checks, preset, 640, 480)
    R = robot.T_base_ee(spec.q)[:, :3, :3]
    closest = min(rotation_angle(R[i], R[j]) for i in range(len(R)) for j in range(i))
    assert np.rad2deg(closest) > 5  # stations, not a slow motion: hand-eye needs distinct rotations


def test_stations_refuse_an_impossible_tilt():
    import yaml

    content = yaml.safe_load(open("scenes/targeting-stations.yaml"))
    with pytest.raises(UserError, match="stations.max_tilt_deg = 95: input should be less than 90"):
        parse_preset({**content, "stations": {"max_tilt_deg": 95}})
    with pytest.raises(UserError, match="unknown key 'stations.tilt'"):
        parse_preset({**content, "stations": {"tilt": 10}})


def test_distractors_stand_clear_of_the_robot_or_are_left_out_and_counted():
    """Every object placed keeps its centre 0.3 m from the base and the end-effector's path; an object with no
    such place is not placed at a rejected one but left out, and counted."""
    preset = parse_preset({**load_preset("mini").model_dump(), "distractors": {"count": [3, 3], "size": [0.1, 0.2]}})
    path = np.array([[0.5, 0.2, 0.4], [0.6, -0.3, 0.5], [-0.4, 0.5, 0.3]])
    for seed in range(20):
        objects, dropped = distractors(np.random.default_rng(seed), preset, path)
        assert len(objects) + dropped == 3
        for obj in objects:
            xy = obj.T_base_obj[:2, 3]
            assert np.linalg.norm(xy) > 0.3 and np.linalg.norm(path[:, :2] - xy, axis=1).min() > 0.3
    grid = np.stack(np.meshgrid(np.linspace(-1.6, 1.6, 12), np.linspace(-1.6, 1.6, 12)), -1).reshape(-1, 2)
    objects, dropped = distractors(np.random.default_rng(0), preset, np.c_[grid, np.zeros(len(grid))])
    assert objects == [] and dropped == 3


def test_left_out_distractors_are_recorded_in_the_scene(tmp_path):
    meta = SceneMeta(obj_id=1, arm="ur5e", end_effector="robotiq_2f85", joint_names=["j"], T_cam_base=np.eye(4))
    mask = np.zeros((4, 6), bool)
    mask[1:3, 2:4] = True
    frame = Frame(im_id=0, rgb=np.zeros((4, 6, 3), np.uint8), depth=np.ones((4, 6)), mask=mask, mask_visib=mask,
                  K=np.array([[5.0, 0, 3], [0, 5.0, 2], [0, 0, 1]]), T_cam_ee=np.eye(4), joint_positions=np.zeros(1),
                  T_base_ee=np.eye(4))
    for dropped in (2, 0):
        SceneWriter(tmp_path / str(dropped), dataclasses.replace(meta, dropped_distractors=dropped), [1]).write(frame)
        assert read_scene(tmp_path / str(dropped))[0].dropped_distractors == dropped
    # scenes that lost none keep the bytes they had before the record existed
    assert "dropped_distractors" not in json.loads((tmp_path / "0" / "scene_robot.json").read_text())


def test_hard_cases_are_off_unless_asked_and_leave_the_plain_plan_as_it_was(ur5e_checks):
    """A preset without `hard:` keeps its digest (no key added) and plans the same segment as before the
    section existed; an occluder or arm-coloured objects are drawn after the plain plan, so its camera and
    motion stay."""
    from syneepose.preset import with_hard_cases

    robot, checks = ur5e_checks
    preset = load_preset("mini")
    assert "hard" not in preset.digest_content()
    plain = _planned_twice(preset, robot, checks, 3, 0, 16, 320, 240)
    assert plain.occluders == [] and all(d.kind != "capsule" for d in plain.distractors)
    for case in ("occluder", "arm_coloured"):
        spec = _planned_twice(with_hard_cases(preset, [case]), robot, checks, 3, 0, 16, 320, 240)
        np.testing.assert_array_equal(spec.q, plain.q)
        np.testing.assert_array_equal(spec.T_base_cam, plain.T_base_cam)
        assert with_hard_cases(preset, [case]).digest_content()["hard"][case] is not None


def test_an_exit_run_is_out_of_view_and_the_other_frames_whole_in_view(ur5e_checks):
    from syneepose.preset import with_hard_cases
    from syneepose.scene.hard import free_frames

    robot, checks = ur5e_checks
    preset = with_hard_cases(load_preset("mini"), ["exit"])
    for stream in (1, 2, 3):
        spec = _planned_twice(preset, robot, checks, stream, 23, 16, 320, 240)
        inside, visible = checks.check(spec.q, spec.T_base_cam, spec.K, 320, 240)
        out = inside == 0.0
        k = out.sum()
        assert 0.2 * 16 - 1 <= k <= 0.4 * 16 + 1
        assert np.ptp(np.flatnonzero(out)) == k - 1  # one run
        keep = ~out & ~free_frames(out)
        assert (inside[keep] >= 0.999).all() and (visible[keep] >= preset.camera.min_visible).all()


def test_the_occluder_crosses_the_line_of_sight_between_camera_and_end_effector(ur5e_checks):
    """At its crossing frame the occluder's centre projects onto the end-effector's origin and lies between
    the camera and it; it slides level with the floor, so some frames later it is off that line."""
    from kernel.camera import project
    from syneepose.preset import with_hard_cases

    robot, checks = ur5e_checks
    preset = with_hard_cases(load_preset("mini"), ["occluder"])
    spec = _planned_twice(preset, robot, checks, 3, 0, 16, 320, 240)
    [occluder] = spec.occluders
    assert occluder.T_base_obj.shape == (16, 4, 4)
    T_cam_base = inv_T(spec.T_base_cam)
    ee = transform_points(T_cam_base, robot.T_base_ee(spec.q)[:, :3, 3])
    centre = transform_points(T_cam_base, occluder.T_base_obj[:, :3, 3])
    gap = np.linalg.norm(project(ee, spec.K, min_z=1e-6) - project(centre, spec.K, min_z=1e-6), axis=1)
    crossing = int(np.argmin(gap))
    assert gap[crossing] < 1.0
    assert 0.6 * ee[crossing, 2] < centre[crossing, 2] < 0.9 * ee[crossing, 2]
    assert gap.max() > 20.0
    eye, ee_base = spec.T_base_cam[:3, 3], robot.T_base_ee(spec.q)[:, :3, 3]
    share = np.linalg.norm(occluder.T_base_obj[crossing, :3, 3] - eye) / np.linalg.norm(ee_base[crossing] - eye)
    sideways = occluder.T_base_obj[:, :3, 3] - (eye + share * (ee_base - eye))
    np.testing.assert_allclose(sideways[:, 2], 0.0, atol=1e-6)


def test_arm_coloured_objects_are_the_arms_colour_and_seen_behind_the_robot(ur5e_checks):
    from kernel.camera import project
    from syneepose.preset import with_hard_cases
    from syneepose.scene.hard import arm_colours

    robot, checks = ur5e_checks
    preset = with_hard_cases(load_preset("mini"), ["arm_coloured"])
    spec = _planned_twice(preset, robot, checks, 3, 0, 16, 320, 240)
    capsules = [d for d in spec.distractors if d.kind == "capsule"]
    assert len(capsules) + spec.dropped_distractors >= 1 and capsules
    T_cam_base = inv_T(spec.T_base_cam)
    farthest = np.linalg.norm(transform_points(T_cam_base, robot.T_base_ee(spec.q)[:, :3, 3]), axis=1).max()
    colours, shares = arm_colours(robot)
    assert shares.sum() == pytest.approx(1.0) and len(colours) >= 2
    for capsule in capsules:
        assert np.min(np.abs(colours - capsule.surface.color_a).max(1)) < 1e-9 and capsule.surface.kind == "plain"
        floor = transform_points(T_cam_base, np.r_[capsule.T_base_obj[:2, 3], 0.0][None])[0]
        u, v = project(floor, spec.K, min_z=1e-6)
        assert 0 <= u < 320 and 0 <= v < 240 and np.linalg.norm(floor) > farthest
        assert capsule.radius is not None and 0.3 < np.linalg.norm(capsule.T_base_obj[:2, 3]) < 1.4
