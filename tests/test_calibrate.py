"""`python -m feepe calibrate`: a recording (a ROS 2 bag written with rosbags, or a folder) in, the
camera-to-base transform out in forms a robot stack loads; the same calibration as eval.run on the BOP scene
the recording was made from; bad recordings are one line and nothing written."""

import csv
import io
import json
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from feepe.calibrate.bag import colour_image, depth_image
from feepe.calibrate.outputs import Frames, as_handeye_yaml, as_json, as_static_transform_publisher, as_urdf_joint
from feepe.calibrate.recording import Recording, interpolate_joints, intrinsics, nearest, thinned
from feepe.calibrate.uncertainty import estimate
from feepe.calibrate.verdict import judge
from kernel.errors import UserError
from kernel.transforms import inv_T, make_T
from eval.recordings import write_bag, write_folder
from tests.test_kernel_boundary import BLOCKER, REPO

FRAMES = Frames("base", "camera_color_optical_frame", "ee_mount")


def _T(t, q) -> np.ndarray:
    return make_T(Rotation.from_quat(q).as_matrix(), t)


@pytest.mark.parametrize("euler_deg", [(10, -35, 120), (0, 90, 30), (-170, -89.9999, 5), (180, 0, 0)])
def test_every_written_form_gives_back_the_same_transform(euler_deg):
    T = make_T(Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix(), [0.91, -0.064, 1.42])
    loaded = {}
    doc = json.loads(json.dumps(as_json(T, FRAMES, {})))
    loaded["json matrix"] = np.array(doc["T_base_camera"])
    loaded["json t, q"] = _T(doc["translation_m"], doc["quaternion_xyzw"])
    handeye = yaml.safe_load(as_handeye_yaml(T, FRAMES, "rec"))["transform"]
    loaded["easy_handeye2"] = _T([handeye["translation"][k] for k in "xyz"], [handeye["rotation"][k] for k in "xyzw"])
    command = as_static_transform_publisher(T, FRAMES).splitlines()[-1]
    args = dict(re.findall(r"--([\w-]+) (\S+)", command))
    assert args["frame-id"] == "base" and args["child-frame-id"] == "camera_color_optical_frame"
    loaded["static tf"] = _T([float(args[k]) for k in ("x", "y", "z")], [float(args[k]) for k in ("qx", "qy", "qz", "qw")])
    origin = ET.fromstring(as_urdf_joint(T, FRAMES).split("-->")[1]).find("origin")
    rpy = [float(v) for v in origin.get("rpy").split()]
    loaded["urdf joint"] = make_T(Rotation.from_euler("xyz", rpy).as_matrix(), [float(v) for v in origin.get("xyz").split()])
    for form, U in loaded.items():
        assert np.abs(U - T).max() < 1e-9, form


def test_streams_pair_by_stamp_and_joints_interpolate_between_messages():
    assert nearest(np.array([0.0, 0.033, 0.066]), 0.04, 0.02) == 1 and nearest(np.array([0.0]), 0.5, 0.02) is None
    stamps, q = np.array([0.0, 0.01, 0.5]), np.array([[0.0], [1.0], [2.0]])
    assert interpolate_joints(stamps, q, 0.005, 0.1)[0] == pytest.approx(0.5)
    assert interpolate_joints(stamps, q, 0.2, 0.1) is None  # messages around it 0.49 s apart
    assert interpolate_joints(stamps, q, -0.1, 0.1) is None
    K = [[600, 0, 320], [0, 601, 240], [0, 0, 1]]
    for info in ({"k": sum(K, [])}, {"camera_matrix": {"data": sum(K, [])}}, {"fx": 600, "fy": 601, "cx": 320, "cy": 240}):
        assert np.array_equal(intrinsics(info, "x")[0], K)
    with pytest.raises(UserError, match="no intrinsics"):
        intrinsics({"D": [0]}, "camera_info.yaml")
    ten = Recording("x", 10, lambda: iter(range(10)))
    assert thinned(ten, 4).count == 3 and list(thinned(ten, 4).read()) == [0, 4, 8]


def test_ros_images_decode_as_rep_118_says():
    class Msg:
        def __init__(self, array, encoding):
            self.height, self.width = array.shape[:2]
            self.encoding, self.is_bigendian, self.step = encoding, 0, array.strides[0]
            self.data = np.ascontiguousarray(array).view(np.uint8).reshape(-1)

    mm = np.array([[0, 1000], [1500, 65535]], np.uint16)
    assert np.array_equal(depth_image(Msg(mm, "16UC1")), mm * 1e-3)
    metres = np.array([[np.nan, 1.0], [np.inf, 0.25]], np.float32)
    assert np.array_equal(depth_image(Msg(metres, "32FC1")), [[0, 1.0], [0, 0.25]])
    rgb = np.arange(24, dtype=np.uint8).reshape(2, 4, 3)
    assert np.array_equal(colour_image(Msg(rgb[..., ::-1].copy(), "bgr8")), rgb)
    with pytest.raises(UserError, match="yuv422"):
        colour_image(Msg(rgb, "yuv422"))


def test_the_verdict_says_what_is_wrong_and_what_motion_would_help():
    T = np.stack([make_T(Rotation.from_euler("z", 30 * i, degrees=True).as_matrix(), [0.4 + 0.1 * i, 0.1 * (i % 2), 0.3])
                  for i in range(6)])
    good = estimate([make_T(t=[0, 0, 1e-4 * i]) for i in range(8)], make_T(t=[0, 0, 7e-4]), T[:, :3, 3], 3.0, 4.0)
    assert judge(6, 6, 0.5, 0.9, good, T).word == "OK"
    assert judge(6, 6, 3.0, 0.9, good, T).word == "POOR FIT"
    assert judge(6, 0, np.nan, np.nan, good, T).word == "NO CALIBRATION"
    still = np.repeat(T[:1], 6, axis=0)
    assert judge(6, 6, 0.5, 0.9, good, still).word == "TOO LITTLE MOTION"
    wide = estimate([make_T(t=[0, 0, 0.01 * i]) for i in range(8)], make_T(t=[0, 0, 0.07]), T[:, :3, 3], 3.0, 4.0)
    verdict = judge(6, 6, 0.5, 0.9, wide, T)
    assert verdict.word == "UNCERTAIN" and "2-sigma" in verdict.line()


def _scene(tiny_dataset) -> Path:
    return next(s for s in sorted((tiny_dataset / "test").iterdir())
                if "robotiq_2f85" in (s / "scene_robot.json").read_text())


def _calibrate(tiny_dataset, assets, recording: Path, out: Path, *extra, urdf=None, ee_link="ee_mount",
               no_generator=False):
    """`no_generator`: with syneepose, eval, bpy and mujoco not importable (as on a robot's computer)."""
    templates = next((tiny_dataset / "templates").glob("robotiq_2f85_*"))
    command = ["-c", BLOCKER, str(REPO / "feepe" / "__main__.py")] if no_generator else ["-m", "feepe"]
    cmd = [sys.executable, *command, "calibrate", str(recording), "--urdf",
           str(urdf or assets / "robots" / "ur5e+robotiq_2f85.urdf"), "--ee-link", ee_link, "--base-link", "base",
           "--templates", str(templates), "--model", str(tiny_dataset / "models" / "obj_000002.ply"),
           "--out", str(out), "--quiet", *extra]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)


def _eval_calibration(tiny_dataset, scene: Path, out: Path) -> np.ndarray:
    """eval.run's calibration after the scene's last frame, --masks none."""
    cmd = [sys.executable, "-m", "eval.run", "--method", "feepe", "--dataset", str(tiny_dataset), "--masks", "none",
           "--scenes", str(int(scene.name)), "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-2000:]
    last = (out / "results.csv").read_text().strip().splitlines()[-1].split(",")
    T_cam_ee = make_T(np.array(last[4].split(), float).reshape(3, 3), np.array(last[5].split(), float) / 1000)
    frames = json.loads((scene / "scene_robot.json").read_text())["frames"]
    return T_cam_ee @ inv_T(np.array(frames[last[1]]["T_base_ee"]))


def test_a_ros2_bag_and_a_folder_give_the_calibration_eval_run_gives_on_the_scene(tiny_dataset, assets, tmp_path):
    """A ROS 2 bag (MCAP, realsense2-like topics, the depth stamps wandering 8 ms from the colour's), written
    and calibrated by `eval.calibration_tool` as a user runs the tool, and a recording folder of the same
    rendered segment (read with the generator and the evaluator not importable): the transform written is
    eval.run's --masks none calibration of the same frames to 0.1 mm, in every form."""
    scene = _scene(tiny_dataset)
    expected = inv_T(_eval_calibration(tiny_dataset, scene, tmp_path / "eval"))
    tool = [sys.executable, "-m", "eval.calibration_tool", str(tiny_dataset), "--scenes", str(int(scene.name)),
            "--out", str(tmp_path / "tool")]
    proc = subprocess.run(tool, capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-2000:]
    segment = next(csv.DictReader(io.StringIO((tmp_path / "tool" / "segments.csv").read_text())))
    assert float(segment["error_mm"]) < 10  # at the workspace, against the truth
    # six frames leave two calibrations in the second half: too few to state a bound, and the verdict says so
    assert segment["two_sigma_mm"] == "" and segment["verdict"] == "UNCERTAIN"
    write_folder(scene, tmp_path / "rec_folder")
    proc = _calibrate(tiny_dataset, assets, tmp_path / "rec_folder", tmp_path / "out_folder", no_generator=True)
    assert proc.returncode == 0 and "verdict:" in proc.stdout, proc.stderr[-2000:]
    bag_run = tmp_path / "tool" / "runs" / scene.name
    for out in (bag_run, tmp_path / "out_folder"):
        doc = json.loads((out / "calibration.json").read_text())
        T = np.array(doc["T_base_camera"])
        assert np.linalg.norm(T[:3, 3] - expected[:3, 3]) < 1e-4, out
        assert np.degrees(Rotation.from_matrix(T[:3, :3].T @ expected[:3, :3]).magnitude()) < 0.01, out
        assert doc["estimated_frames"] == doc["frames"] == 6 and doc["parent_frame"] == "base"
        handeye = yaml.safe_load((out / "easy_handeye2.yaml").read_text())["transform"]
        assert np.allclose([handeye["translation"][k] for k in "xyz"], T[:3, 3], atol=1e-9)
        rows = (out / "frames.csv").read_text().splitlines()
        assert len(rows) == 7 and all(np.isfinite(float(r.split(",")[6])) for r in rows[1:])  # depth_mm
        assert (out / "report.html").is_file() and (out / "overlay.gif").is_file()
    # solved again from the samples the bag's run saved, not the bag: the same calibration
    T_bag = np.array(json.loads((bag_run / "calibration.json").read_text())["T_base_camera"])
    shutil.rmtree(tmp_path / "tool" / "bags")
    proc = subprocess.run([sys.executable, "-m", "feepe", "calibrate", "--resume", "--out", str(bag_run), "--quiet"],
                          capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    again = np.array(json.loads((bag_run / "calibration.json").read_text())["T_base_camera"])
    assert np.abs(again - T_bag).max() < 1e-12


def test_flange_poses_and_given_masks_calibrate_by_the_end_effector_alone(tiny_dataset, assets, tmp_path):
    """Without joint states the arm cannot be placed: the end-effector's masks are asked for, and with them
    its outline alone gives a calibration near the truth."""
    scene = _scene(tiny_dataset)
    write_folder(scene, tmp_path / "rec", masks=True, flange=True)
    _one_line_nothing_written(_calibrate(tiny_dataset, assets, tmp_path / "rec", tmp_path / "o1"), tmp_path / "o1",
                              "with flange poses instead of joint states")
    proc = _calibrate(tiny_dataset, assets, tmp_path / "rec", tmp_path / "o2", "--masks", "given")
    assert proc.returncode == 0, proc.stderr[-2000:]
    T = np.array(json.loads((tmp_path / "o2" / "calibration.json").read_text())["T_base_camera"])
    truth = inv_T(np.array(json.loads((scene / "scene_robot.json").read_text())["T_cam_base"]))
    assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 0.02
    assert "outline not measured" in proc.stdout


def test_ros1_and_sqlite3_bags_read_as_the_mcap_one(tiny_dataset, tmp_path):
    """The three containers rosbags reads give the same paired frames: images, depth, intrinsics, joints."""
    from feepe.calibrate.bag import Topics, read_bag

    scene = _scene(tiny_dataset)
    read = {}
    for storage, name in (("mcap", "a"), ("sqlite3", "b"), ("ros1", "c.bag")):
        write_bag(scene, tmp_path / name, storage=storage)
        read[storage] = list(read_bag(tmp_path / name, Topics(), 0.02, 0.1).read())
    assert len(read["mcap"]) == 6
    for storage in ("sqlite3", "ros1"):
        for a, b in zip(read["mcap"], read[storage], strict=True):
            assert a.name == b.name and np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth)
            assert np.array_equal(a.K, b.K) and a.joints == b.joints


def test_a_folder_takes_joint_states_as_csv_or_json(tmp_path):
    """The same frames with the joints in joint_states.csv or joint_states.json read the same."""
    import cv2

    from feepe.calibrate.folder import read_folder

    (tmp_path / "rgb").mkdir()
    cv2.imwrite(str(tmp_path / "rgb" / "a.png"), np.zeros((4, 6, 3), np.uint8))
    (tmp_path / "camera_info.yaml").write_text("k: [5, 0, 3, 0, 5, 2, 0, 0, 1]\n")
    (tmp_path / "joint_states.csv").write_text("frame,j1,j2\na,0.5,-1\n")
    from_csv = next(read_folder(tmp_path).read())
    (tmp_path / "joint_states.csv").unlink()
    (tmp_path / "joint_states.json").write_text(json.dumps({"a": {"j1": 0.5, "j2": -1}}))
    from_json = next(read_folder(tmp_path).read())
    assert from_csv.joints == from_json.joints == {"j1": 0.5, "j2": -1.0} and from_json.depth is None
    (tmp_path / "joint_states.json").write_text(json.dumps({"b": {"j1": 0.5}}))
    with pytest.raises(UserError, match="no row for frame"):
        read_folder(tmp_path)


def _one_line_nothing_written(proc, out: Path, words: str) -> None:
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and words in lines[0], proc.stderr
    assert not out.exists()


def test_a_bad_recording_is_one_line_and_nothing_written(tiny_dataset, assets, tmp_path):
    scene = _scene(tiny_dataset)
    write_bag(scene, tmp_path / "no_depth", skip_topic="depth")
    _one_line_nothing_written(_calibrate(tiny_dataset, assets, tmp_path / "no_depth", tmp_path / "o1"),
                              tmp_path / "o1", "no topic /camera/camera/aligned_depth_to_color/image_raw")
    write_bag(scene, tmp_path / "late_depth", depth_offset_s=0.25)  # half the frames' period
    _one_line_nothing_written(_calibrate(tiny_dataset, assets, tmp_path / "late_depth", tmp_path / "o2"),
                              tmp_path / "o2", "no colour frame has a depth image within 0.02 s")
    write_bag(scene, tmp_path / "rec")
    _one_line_nothing_written(_calibrate(tiny_dataset, assets, tmp_path / "rec", tmp_path / "o3", ee_link="tool0"),
                              tmp_path / "o3", "--ee-link 'tool0' is not a link of ur5e+robotiq_2f85.urdf")
    renamed = tmp_path / "renamed.urdf"  # the robot's URDF naming its elbow otherwise than the joint states do
    renamed.write_text((assets / "robots" / "ur5e+robotiq_2f85.urdf").read_text().replace('"elbow_joint"', '"elbow"'))
    proc = _calibrate(tiny_dataset, assets, tmp_path / "rec", tmp_path / "o4", "--mesh-dir", str(assets / "robots"),
                      urdf=renamed)
    _one_line_nothing_written(proc, tmp_path / "o4", "joint states lack the arm joint(s) elbow of renamed.urdf")
