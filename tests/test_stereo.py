"""Simulated active-stereo depth: sub-pixel matching, re-projection, a rendered plane at a known distance,
and the `--depth stereo` layout."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
import yaml

from kernel.bop import read_frame, read_scene, split_dir
from kernel.transforms import make_T
from syneepose.scene.spec import IR_RENDERS
from syneepose.stereo import INTEL_SUBPIXEL, SENSORS_DIR, load_profile, plane_rms, refine_disparity, to_rgb_camera

PLANE_SCRIPT = """
import sys, numpy as np
from pathlib import Path
from syneepose.blender import scene as bscene
from syneepose.blender.stereo import IrRig
from syneepose.ir_shading import Lighting
from syneepose.scene.spec import Plane, Surface
from syneepose.stereo import load_profile, stereo_depth, to_rgb_camera
from kernel.transforms import make_T
W, H, dist, out, ir_render = 320, 240, float(sys.argv[1]), sys.argv[2], sys.argv[3]
f = W / 2 / np.tan(np.deg2rad(30))
K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1.0]])
profile = load_profile("d435", ir_render)
bscene.reset(W, H, 4, False, 4, (0.3, 0.3, 0.3), 1.0)
bscene.set_camera(K, W, H, np.eye(4))
grey = Surface("plain", (0.5, 0.5, 0.5), (0.5, 0.5, 0.5), 1.0)
bscene.add_planes([Plane(make_T(np.diag([1.0, -1.0, -1.0]), [0, 0, dist]), (6.0, 6.0), grey)])
rig = IrRig(profile, W, H, seed=0, lighting=Lighting.of([], (0.3, 0.3, 0.3), 1.0, profile.ambient))
exact = bscene.render(Path(out).parent)["depth"]
left, right = rig.render_pair(np.eye(4), Path(out).parent)
sensed = to_rgb_camera(stereo_depth(left, right, profile, rig.K_ir), rig.K_ir, profile.T_rgb_irleft, K, W, H)
np.savez(out, exact=exact, sensed=sensed, after=bscene.render(Path(out).parent)["depth"])
"""


def test_refinement_recovers_a_sub_pixel_shift():
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (120, 200)).astype(np.float32), (0, 0), 1.0)
    shift = 7.3  # left(x) = right(x - 7.3)
    xs, ys = np.meshgrid(np.arange(200, dtype=np.float32), np.arange(120, dtype=np.float32))
    left = cv2.remap(texture, xs - shift, ys, cv2.INTER_CUBIC)
    start = np.full((120, 200), 7.0, np.float32)  # a whole-pixel guess, as SGBM locks to
    d = refine_disparity(left, texture, start, window=11, iterations=5)
    assert abs(np.median(d[20:-20, 30:-20]) - shift) < 0.05  # half the 0.1 px noise the profile models


def test_refinement_stays_put_from_whole_pixel_guesses_around_a_half_pixel_shift():
    """A dot texture shifted by 7.5 px, SGBM's guesses 7 or 8 at random: each window is matched at its own
    pixel's disparity, so more iterations converge instead of spreading (they spread to over 1 px when every
    pixel stepped by its window's mean error)."""
    rng = np.random.default_rng(2)
    dots = (rng.uniform(size=(120, 600)) < 0.1).astype(np.float32) * 255  # a third of a pixel per dot cell
    texture = cv2.resize(cv2.GaussianBlur(dots, (0, 0), 1.0), (200, 120), interpolation=cv2.INTER_AREA)
    shift = 7.5
    xs, ys = np.meshgrid(np.arange(200, dtype=np.float32), np.arange(120, dtype=np.float32))
    left = cv2.remap(texture, xs - shift, ys, cv2.INTER_CUBIC)
    start = rng.choice([7.0, 8.0], size=(120, 200)).astype(np.float32)
    for iterations in (5, 20):
        d = refine_disparity(left, texture, start, window=7, iterations=iterations)[10:-10, 20:-10]
        assert np.percentile(np.abs(d - shift), 95) < 0.05


def test_reprojection_is_the_identity_for_a_shared_camera_and_keeps_the_nearest_surface():
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    depth = np.full((48, 64), 2.0)
    depth[10:20, 10:20] = 1.0
    depth[30:, :5] = 0.0
    np.testing.assert_allclose(to_rgb_camera(depth, K, np.eye(4), K, 64, 48), depth)
    # seen from 10 cm to the right the near square moves left and covers the far plane there
    moved = to_rgb_camera(depth, K, make_T(t=[-0.1, 0.0, 0.0]), K, 64, 48)
    assert (moved[10:20, 0:10] == 1.0).all() and (moved[12:18, 3:7] > 0).all()
    assert moved.min() == 0.0  # what no IR pixel reaches stays empty


@pytest.mark.parametrize("ir_render", IR_RENDERS)
def test_stereo_plane_matches_the_profile_noise(tmp_path, assets, ir_render):
    """A grey plane 1 m away: median error within the profile's 0.1 px disparity noise, holes only where
    the right imager cannot see (the left border), and the exact depth untouched."""
    out = tmp_path / "plane.npz"
    proc = subprocess.run([sys.executable, "-c", PLANE_SCRIPT, "1.0", str(out), ir_render], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    r = np.load(out)
    profile = load_profile("d435")
    sigma = 1.0**2 * 0.1 / (profile.ir_K(320, 240)[0, 0] * profile.baseline)  # z^2 dd / (f b): 0.1 px at 1 m
    valid = r["sensed"] > 0
    err = r["sensed"][valid] - 1.0
    assert abs(np.median(err)) <= sigma and np.median(np.abs(err)) <= sigma
    # unmatched: the columns the right imager does not see (disparity at 1 m, in RGB pixels, plus the block)
    f_ir, f_rgb = profile.ir_K(320, 240)[0, 0], 160 / np.tan(np.deg2rad(30))
    border = int(np.ceil((f_ir * profile.baseline + 8) * f_rgb / f_ir)) + 2
    assert valid[:, border:].mean() > 0.995
    np.testing.assert_allclose(r["exact"], 1.0, atol=1e-4)
    np.testing.assert_array_equal(r["after"], r["exact"])  # the IR pass leaves the RGB set-up as it was
    if ir_render == "shaded":  # the plane-fit RMS within 15 % of Intel's model for the D4xx (issue 36)
        K = np.array([[f_rgb, 0, 159.5], [0, f_rgb, 119.5], [0, 0, 1.0]])
        rms = plane_rms(r["sensed"], K, 0.8)[0]
        assert abs(rms * f_ir * profile.baseline / INTEL_SUBPIXEL - 1.0) < 0.15


def test_depth_stereo_layout_and_profile(tmp_path, assets):
    proc = subprocess.run([sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--out", str(tmp_path),
                           "--robots", "ur5e+robotiq_2f85", "--frames", "1", "--resolution", "96x72", "--samples",
                           "2", "--depth", "stereo"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    info = json.loads((tmp_path / "dataset_info.json").read_text())
    assert info["depth"] == "stereo" and info["sensor"]["name"] == "d435" and info["depth_dirs"]["depth_gt"] == "exact"
    assert info["sensor"]["ir_render"] == "shaded"
    [scene] = sorted(split_dir(tmp_path).iterdir())
    meta, ids = read_scene(scene)
    frame = read_frame(scene, ids[0])
    assert meta.depth_sensor["mode"] == "stereo" and frame.depth_gt is not None and frame.ir_left is None
    assert (frame.depth_gt > 0).all() and (frame.depth == 0).any()  # the sensor has holes, the truth none
    proc = subprocess.run([sys.executable, "-m", "eval.depth_error", str(tmp_path), "--out", str(tmp_path / "h.png")],
                          capture_output=True, text=True)
    assert proc.returncode == 0 and "robotiq_2f85: median" in proc.stdout and (tmp_path / "h.png").stat().st_size > 5000
    proc = subprocess.run([sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--out", str(tmp_path),
                           "--robots", "ur5e+robotiq_2f85", "--frames", "1", "--resolution", "96x72", "--samples", "2"],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "depth stereo -> exact" in proc.stderr and "Traceback" not in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--out", str(tmp_path),
                           "--robots", "ur5e+robotiq_2f85", "--frames", "1", "--resolution", "96x72", "--samples", "2",
                           "--depth", "stereo", "--sensor-render", "pathtraced"], capture_output=True, text=True)
    assert proc.returncode == 2 and "sensor_sha256" in proc.stderr  # another IR rendering is another sensor
    # the projector's depth map rendered by Cycles instead of splatted from the imagers: the same sensor but for
    # the noise, which any change of the images re-draws (median |error| 15.5 and 16.7 mm here, holes 1 %)
    rendered = tmp_path / "d435-rendered.yaml"
    profile = yaml.safe_load((SENSORS_DIR / "d435.yaml").read_text())
    rendered.write_text(yaml.safe_dump({**profile, "projector": {**profile["projector"], "shadow": "rendered"}}))
    proc = subprocess.run([sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--out", str(tmp_path / "r"),
                           "--robots", "ur5e+robotiq_2f85", "--frames", "1", "--resolution", "96x72", "--samples", "2",
                           "--depth", "stereo", "--sensor", str(rendered)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    other = read_frame(sorted(split_dir(tmp_path / "r").iterdir())[0], ids[0])
    errors = [np.median(np.abs(f.depth - f.depth_gt)[f.depth > 0]) for f in (frame, other)]
    assert abs(errors[0] / errors[1] - 1) < 0.2 and abs((frame.depth > 0).mean() - (other.depth > 0).mean()) < 0.01
    proc = subprocess.run([sys.executable, "-m", "syneepose", "render", "--out", str(tmp_path / "x"), "--depth",
                           "stereo", "--sensor", "nope"], capture_output=True, text=True)
    assert proc.returncode == 2 and "sensor profile 'nope' not found" in proc.stderr
