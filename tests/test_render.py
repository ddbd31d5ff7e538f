"""Rendered segments: ground truth agrees with the pixels, runs are reproducible and resumable.

Tiny renders (64x48, 2 samples) through the real CLI, one worker process per segment.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from kernel.bop import read_frame, read_scene, split_dir
from kernel.errors import UserError
from syneepose import paths
from syneepose.devices import gpu_backend
from syneepose.robots.robot import load_robot

# One configuration per end-effector, the arms rotating through.
CONFIGS = ["panda+panda_hand", "ur5e+robotiq_2f85", "ur10e+robotiq_2f140", "panda+kinova_3f",
           "ur5e+robotiq_3f", "ur10e+shadow_hand"]
TINY = ["--resolution", "64x48", "--samples", "2", "--segments", "1"]


def _render(out, *args, **kw):
    cmd = [sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--out", str(out), *TINY, *args]
    return subprocess.run(cmd, capture_output=True, text=True, **kw)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory, assets):
    out = tmp_path_factory.mktemp("render")
    proc = _render(out, "--frames", "2", "--robots", ",".join(CONFIGS))
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out


def _scenes(root):
    return sorted(p for p in split_dir(root).iterdir() if p.is_dir())


def _raycast(mesh_m, T_cam_model, K, width, height):
    """Independent reference: model depth along each pixel-centre ray (inf where missed)."""
    mesh = mesh_m.copy().apply_transform(T_cam_model)
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    dirs = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(u.shape)], -1).reshape(-1, 3)
    locs, ray, _ = mesh.ray.intersects_location(np.zeros_like(dirs), dirs, multiple_hits=False)
    z = np.full(len(dirs), np.inf)
    z[ray] = locs[:, 2]
    return z.reshape(height, width)


def test_layout(rendered):
    info = json.loads((rendered / "dataset_info.json").read_text())
    assert info["preset"] == "mini" and set(CONFIGS) <= set(info["configurations"])
    assert (info["name"], info["split"]) == ("syneepose", "test")
    assert (rendered / "models" / "models_info.json").is_file()
    bop24 = json.loads((rendered / "test_targets_bop24.json").read_text())
    assert json.loads((rendered / "camera.json").read_text())["width"] == 64
    scenes = _scenes(rendered)
    assert len(scenes) == len(CONFIGS) and len(bop24) == 2 * len(CONFIGS)
    for scene in scenes:
        for name in ("scene_camera.json", "scene_gt.json", "scene_gt_info.json", "scene_gt_coco.json",
                     "scene_robot.json"):
            assert (scene / name).is_file()
        assert len(list((scene / "rgb").glob("*.png"))) == 2


def test_ground_truth_matches_pixels(rendered):
    for scene in _scenes(rendered):
        meta, im_ids = read_scene(scene)
        robot = load_robot(f"{meta.arm}+{meta.end_effector}")
        mesh = trimesh.load(rendered / "models" / f"obj_{meta.obj_id:06d}.ply", process=False)
        mesh.apply_scale(0.001)
        for im_id in im_ids:
            f = read_frame(scene, im_id)
            h, w = f.mask.shape
            # Kinematic consistency: sidecar FK, camera-to-base and scene_gt agree.
            np.testing.assert_allclose(robot.T_base_ee(f.joint_positions), f.T_base_ee, atol=1e-6)
            np.testing.assert_allclose(meta.T_cam_base @ f.T_base_ee, f.T_cam_ee, atol=1e-6)
            # Pixels: the model at the GT pose reproduces the full mask and the depth.
            z = _raycast(mesh, f.T_cam_ee, f.K, w, h)
            hit = np.isfinite(z)
            assert f.mask.sum() > 20, (scene.name, im_id)
            iou = (hit & f.mask).sum() / (hit | f.mask).sum()
            assert iou >= 0.95, (scene.name, im_id, iou)
            both = hit & f.mask_visib & (f.depth > 0)
            assert both.sum() > 10
            assert np.median(np.abs(f.depth[both] - z[both])) < 1e-3, scene.name
            assert (f.mask_visib <= f.mask).all()


def _link_mesh(robot, link, T_base_link):
    """The link's visuals in the base frame (metres)."""
    parts = []
    for visual in robot.model.link(link).visuals:
        part = trimesh.load(str(robot.urdf.parent / visual.mesh), force="mesh", process=False)
        parts.append(part.apply_transform(T_base_link[link] @ visual.origin))
    return trimesh.util.concatenate(parts)


def test_link_ids_name_the_visible_robot_part(rendered):
    """Each robot_mask_visib/ pixel names the part the camera sees there: the end-effector's ids are its
    visible mask, and an arm link's pixels lie on that link's own mesh at the rendered depth."""
    checked = 0
    for scene in _scenes(rendered):
        meta, im_ids = read_scene(scene)
        robot = load_robot(f"{meta.arm}+{meta.end_effector}")
        assert meta.links[-1] == robot.ee_root and len(meta.links) == len(set(meta.links)) > 3
        for im_id in im_ids:
            f = read_frame(scene, im_id)
            np.testing.assert_array_equal(f.link_ids == len(meta.links), f.mask_visib)
            T_base_link = robot.T_base_link(f.joint_positions)
            h, w = f.link_ids.shape
            for k in np.unique(f.link_ids[(f.link_ids > 0) & (f.link_ids < len(meta.links))]):
                seen = (f.link_ids == k) & (f.depth > 0)
                if seen.sum() < 5:
                    continue
                mesh = _link_mesh(robot, meta.links[k - 1], T_base_link)
                z = _raycast(mesh, meta.T_cam_base, f.K, w, h)
                assert np.mean(np.abs(f.depth[seen] - z[seen]) < 2e-3) > 0.9, (scene.name, im_id, meta.links[k - 1])
                checked += 1
    assert checked >= 10


def test_same_seed_same_data(rendered, tmp_path):
    again = tmp_path / "again"
    proc = _render(again, "--frames", "2", "--robots", CONFIGS[1])
    assert proc.returncode == 0, proc.stderr[-2000:]
    a = next(s for s in _scenes(rendered) if (split_dir(again) / s.name).is_dir())
    b = split_dir(again) / a.name
    for name in ("scene_camera.json", "scene_gt.json", "scene_gt_info.json", "scene_robot.json"):
        assert (a / name).read_text() == (b / name).read_text(), name
    for im_id in (0, 1):
        fa, fb = read_frame(a, im_id), read_frame(b, im_id)
        assert (fa.rgb == fb.rgb).all() and (fa.mask == fb.mask).all()


def test_same_seed_same_pixels_from_frame_one_on(tmp_path, assets):
    """Cycles' persistent data once put frames 1+ of this segment on one of two RGB outputs (66% of pixels
    apart) in about half the runs; three runs, every PNG byte for byte."""
    runs = []
    for k in range(3):
        out = tmp_path / str(k)
        cmd = [sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--out", str(out), "--resolution",
               "96x72", "--samples", "4", "--segments", "1", "--frames", "3", "--robots", "ur5e+panda_hand"]
        assert subprocess.run(cmd, capture_output=True).returncode == 0
        runs.append({p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*.png"))})
    assert len(runs[0]) >= 12 and runs[0] == runs[1] == runs[2]


def test_killed_render_resumes_to_the_same_result(rendered, tmp_path):
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--out", str(out), *TINY,
           "--frames", "4", "--robots", CONFIGS[1]]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    gt = None
    deadline = time.time() + 120
    while time.time() < deadline:
        found = list(out.glob("test/*/scene_gt.json"))
        if found and len(json.loads(found[0].read_text() or "{}")) >= 1:
            gt = found[0]
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert gt is not None
    assert len(json.loads(gt.read_text())) < 4
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    ref = tmp_path / "ref"
    assert subprocess.run([*cmd[:7], str(ref), *cmd[8:]], capture_output=True).returncode == 0
    for name in ("scene_camera.json", "scene_gt.json", "scene_gt_info.json", "scene_gt_coco.json", "scene_robot.json"):
        assert (gt.parent / name).read_text() == (split_dir(ref) / gt.parent.name / name).read_text()
    for name in ("camera.json", "test_targets_bop19.json", "test_targets_bop24.json"):
        assert (out / name).read_text() == (ref / name).read_text()
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]


def _group(pgid: int) -> list[int]:
    """Live processes of a process group (the render and every worker it spawned)."""
    pids = []
    for d in Path("/proc").iterdir():
        try:
            stat = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if stat[0] != "Z" and int(stat[2]) == pgid:
            pids.append(int(d.name))
    return pids


@pytest.fixture(scope="module")
def four_frames(tmp_path_factory, assets):
    out = tmp_path_factory.mktemp("four")
    proc = _render(out, "--frames", "4", "--robots", CONFIGS[1], "--workers", "2")
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out


@pytest.mark.parametrize("sig,whom", [(signal.SIGINT, "group"), (signal.SIGTERM, "main"), (signal.SIGKILL, "main")],
                         ids=["ctrl-c", "sigterm", "kill-9-main"])
def test_a_stopped_render_stops_every_worker_and_resumes(four_frames, tmp_path, sig, whom):
    """Ctrl-C (the terminal signals the whole group), a scheduler's SIGTERM to the main process, or the main
    process killed outright: within 5 s no worker renders on, only whole frames stay, and a rerun ends
    with the files of an uninterrupted run."""
    out = tmp_path / "stopped"
    cmd = [sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--out", str(out), *TINY,
           "--frames", "4", "--robots", CONFIGS[1], "--workers", "2"]
    # as from a terminal's foreground: a shell starts background jobs (and so `make test &`) with Ctrl-C
    # ignored, and a program started so ignores it too (the render then ran on to its end and exited 0)
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 120
    while time.time() < deadline and not any(json.loads(p.read_text() or "{}")
                                              for p in out.glob("test/*/scene_gt.json")):
        time.sleep(0.05)
    assert len(_group(proc.pid)) >= 2  # the render and its worker
    t0 = time.time()
    os.killpg(proc.pid, sig) if whom == "group" else os.kill(proc.pid, sig)
    proc.wait(timeout=5)
    while _group(proc.pid) and time.time() - t0 < 5:
        time.sleep(0.05)
    assert not _group(proc.pid), "a worker outlived the render"
    if sig != signal.SIGKILL:
        assert proc.returncode == 130 and proc.stderr.read().decode().strip().endswith("interrupted")
        assert not [p for p in out.rglob("*") if ".tmp" in p.name or p.name.startswith("tmp")]
    [scene] = list(split_dir(out).iterdir())
    assert len(json.loads((scene / "scene_gt.json").read_text())) < 4
    assert subprocess.run(cmd, capture_output=True).returncode == 0
    ref = split_dir(four_frames) / scene.name
    for name in ("scene_camera.json", "scene_gt.json", "scene_gt_info.json", "scene_gt_coco.json", "scene_robot.json"):
        assert (scene / name).read_text() == (ref / name).read_text(), name
    for folder in ("depth", "mask", "mask_visib", "robot_mask_visib"):
        for path in sorted((ref / folder).iterdir()):
            assert (scene / folder / path.name).read_bytes() == path.read_bytes(), path
    assert not [p for p in out.rglob("*") if ".tmp" in p.name or p.name.startswith("tmp")]


@pytest.mark.parametrize("args,word", [
    (["--robots", "ur5e+claw"], "claw"),
    (["--preset", "nosuch"], "nosuch"),
    (["--resolution", "64by48"], "WxH"),
    (["--shard", "3/2"], "shard"),
    (["--threads", "0"], "--threads"),
    (["--executor", "ray", "--ray-address", "127.0.0.1:1"], "nothing answers"),
    (["--executor", "ray", "--ray-address", "head:port"], "HOST:PORT"),
])
def test_bad_input_one_line(tmp_path, args, word):
    cmd = [sys.executable, "-m", "syneepose", "render", "--out", str(tmp_path / "o"), *args]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and word in lines[0]
    assert not (tmp_path / "o").exists()  # refused before anything is written


def test_bad_preset_key_and_unwritable_out(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(Path("scenes/mini.yaml").read_text() + "lighting: {}\n")
    proc = subprocess.run([sys.executable, "-m", "syneepose", "render", "--preset", str(bad), "--out",
                           str(tmp_path / "o")], capture_output=True, text=True)
    assert proc.returncode == 2 and "lighting" in proc.stderr and "Traceback" not in proc.stderr
    blocker = tmp_path / "file"
    blocker.write_text("")
    proc = subprocess.run([sys.executable, "-m", "syneepose", "render", "--out", str(blocker / "x")],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "cannot write" in proc.stderr


def test_templates_reproject_onto_their_masks(tmp_path, assets):
    from kernel.template_set import read_index, read_template, set_dir

    proc = subprocess.run([sys.executable, "-m", "syneepose", "templates", "--out", str(tmp_path), "--ee",
                           "robotiq_2f85,kinova_3f", "--views", "3", "--inplane", "2", "--resolution", "48",
                           "--samples", "2"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    for ee, obj_id in (("robotiq_2f85", 2), ("kinova_3f", 4)):
        folder = set_dir(tmp_path, ee, 3, 2, 48)
        assert len(read_index(folder)) == 6
        mesh = trimesh.load(paths.models_dir(assets) / f"obj_{obj_id:06d}.ply", process=False)
        mesh.apply_scale(0.001)
        for i in range(6):
            t = read_template(folder, i)
            z = _raycast(mesh, t.T_cam_model, t.K, 48, 48)
            hit = np.isfinite(z)
            assert (hit & t.mask).sum() / (hit | t.mask).sum() >= 0.95
            assert np.median(np.abs(t.depth[hit & t.mask] - z[hit & t.mask])) < 1e-3
            near = cv2.dilate(t.mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # anti-aliased rim
            assert (t.rgb[~near] == 0).all()  # black background
            centre = np.argwhere(t.mask).mean(0)
            assert np.abs(centre - 23.5).max() < 8  # object centred


def _ray_task_pids(function: str) -> list[int]:
    """Processes running a Ray task of `function` (Ray names them ray::<function>)."""
    pids = []
    for d in Path("/proc").iterdir():
        try:
            if (d / "cmdline").read_bytes().startswith(f"ray::{function}".encode()):
                pids.append(int(d.name))
        except (OSError, ValueError):
            continue
    return pids


def test_a_ray_task_whose_worker_dies_runs_again_and_ends_as_the_local_render(rendered, tmp_path):
    """The worker of the run's one task is killed (SIGKILL) after its first frame: Ray runs the task again, it
    resumes from the whole frames on disk, and the scene ends byte for byte as the local render's."""
    out = tmp_path / "ray"
    cmd = [sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--out", str(out), *TINY,
           "--frames", "2", "--robots", CONFIGS[1], "--executor", "ray"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    frames_at_kill = None
    deadline = time.time() + 180
    while frames_at_kill is None and time.time() < deadline and proc.poll() is None:
        gt = next(iter(out.glob("test/*/scene_gt.json")), None)
        frames = len(json.loads(gt.read_text() or "{}")) if gt is not None else 0
        pids = _ray_task_pids("run_job")
        if frames and pids:
            frames_at_kill = frames
            for pid in pids:
                os.kill(pid, signal.SIGKILL)
        time.sleep(0.02)
    _, err = proc.communicate(timeout=300)
    assert frames_at_kill == 1, "the worker was not killed mid-segment"
    assert proc.returncode == 0, err[-2000:]
    [scene] = _scenes(out)
    ref = split_dir(rendered) / scene.name
    for name in ("scene_camera.json", "scene_gt.json", "scene_gt_info.json", "scene_gt_coco.json", "scene_robot.json"):
        assert (scene / name).read_text() == (ref / name).read_text(), name
    for folder in ("rgb", "depth", "mask", "mask_visib", "robot_mask_visib"):
        assert sorted(p.name for p in (scene / folder).iterdir()) == sorted(p.name for p in (ref / folder).iterdir())
        for path in (ref / folder).iterdir():
            assert (scene / folder / path.name).read_bytes() == path.read_bytes(), path
    assert not [p for p in out.rglob("*") if ".tmp" in p.name or p.name.startswith("tmp")]


@pytest.mark.parametrize("found, backend", [({"OPTIX": ["RTX A4000"], "CUDA": ["RTX A4000"]}, "OPTIX"),
                                            ({"OPTIX": [], "CUDA": ["GTX 1080"]}, "CUDA"),
                                            ({"CUDA": [], "HIP": ["RX 7900"], "METAL": []}, "HIP")])
def test_gpu_backend_is_the_fastest_that_lists_a_gpu(found, backend):
    assert gpu_backend(found) == backend


@pytest.mark.parametrize("found", [{}, {"OPTIX": [], "CUDA": [], "HIP": []}])
def test_gpu_request_without_a_gpu_is_one_clear_line(found):
    with pytest.raises(UserError, match="no GPU on this machine; render with --device cpu"):
        gpu_backend(found)


def test_gpu_render_runs_where_cycles_lists_a_gpu_and_is_one_clear_line_elsewhere(tmp_path, assets):
    """What Cycles itself lists here decides which: a machine with a GPU renders, one without gets the line."""
    listed = subprocess.run([sys.executable, "-c", "import json; from syneepose.blender.scene import gpu_devices; "
                             "print(json.dumps(gpu_devices()))"], capture_output=True, text=True, check=True)
    has_gpu = any(json.loads(listed.stdout.strip().splitlines()[-1]).values())
    proc = _render(tmp_path, "--frames", "1", "--robots", CONFIGS[1], "--device", "gpu")
    if has_gpu:
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert len(list(tmp_path.rglob("rgb/000000.png"))) == 1
    else:
        assert proc.returncode == 2 and "Traceback" not in proc.stderr
        assert "no GPU" in proc.stderr.strip().splitlines()[-1]
