"""In-plane templates rolled from one render per view (syneepose.templates.roll_template) against the same
templates rendered one by one (--inplane-by rendered)."""

import json
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest

from kernel.template_set import read_index, read_template, set_dir
from kernel.transforms import transform_points
from syneepose.templates import intrinsics, poses, roll_template

VIEWS, INPLANE, RES = 2, 12, 128


def test_rolling_the_image_is_rolling_the_camera():
    """A point seen by view v's unrolled camera lands, after roll_template, where the rolled camera of `poses`
    projects it (no Blender: a 3x3 dot per point, its centroid after the roll)."""
    rng = np.random.default_rng(0)
    centre, radius = np.array([0.01, -0.02, 0.05]), 0.1
    K = intrinsics(RES)
    planned = poses(VIEWS, INPLANE, centre, radius)
    for v in range(VIEWS):
        T0 = planned[v * INPLANE][2]
        for point in centre + rng.uniform(-0.05, 0.05, (5, 3)):
            u0 = K @ transform_points(T0, point[None])[0]
            u0 = np.round(u0[:2] / u0[2]).astype(int)
            mask = np.zeros((RES, RES), bool)
            mask[u0[1] - 1:u0[1] + 2, u0[0] - 1:u0[0] + 2] = True
            depth = np.where(mask, 0.5, 0.0)
            rgb = np.repeat(mask[..., None] * 255, 3, 2).astype(np.uint8)
            for k in range(1, INPLANE):
                _, rolled_depth, rolled = roll_template(rgb, depth, mask, 2 * np.pi * k / INPLANE)
                T_k = planned[v * INPLANE + k][2]
                uk = K @ transform_points(T_k @ np.linalg.inv(T0), (np.linalg.inv(K) @ [*u0, 1.0])[None] * 0.5)[0]
                found = np.argwhere(rolled).mean(0)[::-1]
                assert np.abs(found - uk[:2] / uk[2]).max() <= 0.5
                assert np.allclose(rolled_depth[rolled], 0.5)


@pytest.fixture(scope="module")
def both_sets(tmp_path_factory, assets):
    root = tmp_path_factory.mktemp("inplane")
    for how in ("rendered", "rotated"):
        proc = subprocess.run([sys.executable, "-m", "syneepose", "templates", "--out", str(root / how), "--ee",
                               "robotiq_2f85", "--views", str(VIEWS), "--inplane", str(INPLANE), "--resolution",
                               str(RES), "--samples", "16", "--inplane-by", how], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr[-2000:]
    return [set_dir(root / how, "robotiq_2f85", VIEWS, INPLANE, RES) for how in ("rendered", "rotated")]


def test_rotated_templates_match_rendered_ones(both_sets):
    """Measured at 128 px, 16 spp (2F-85): at multiples of 90 deg the roll is a pixel permutation; between
    them, resampling the point-sampled mask and depth costs about 2 % IoU and a few percent of depths off by
    more than 1 mm at slanted surfaces and edges (docs/syneepose.md, "Templates")."""
    rendered, rotated = both_sets
    index = read_index(rendered)
    assert {r["inplane_by"] for r in read_index(rotated).values()} == {"rotated"}
    for key, rec in index.items():
        a, b = read_template(rendered, int(key)), read_template(rotated, int(key))
        np.testing.assert_allclose(a.T_cam_model, b.T_cam_model)
        iou = (a.mask & b.mask).sum() / (a.mask | b.mask).sum()
        both = a.mask & b.mask
        error_mm = np.abs(a.depth[both] - b.depth[both]) * 1000.0
        assert cv2.PSNR(a.rgb, b.rgb) >= 30.0
        if rec["inplane"] % (INPLANE // 4) == 0:
            assert iou >= 0.999 and (error_mm <= 1.0).mean() >= 0.999
        else:
            assert iou >= 0.97 and np.median(error_mm) <= 0.5 and (error_mm <= 1.0).mean() >= 0.9


def test_a_set_is_not_resumed_the_other_way(both_sets, tmp_path):
    """Half a rendered set, then a rotated rerun: refused in one line, nothing added."""
    rendered, _ = both_sets
    out = tmp_path / "half"
    folder = set_dir(out, "robotiq_2f85", VIEWS, INPLANE, RES)
    shutil.copytree(rendered, folder)
    index = read_index(folder)
    (folder / "templates.json").write_text(json.dumps({k: v for k, v in index.items() if int(k) < 5}))
    proc = subprocess.run([sys.executable, "-m", "syneepose", "templates", "--out", str(out), "--ee", "robotiq_2f85",
                           "--views", str(VIEWS), "--inplane", str(INPLANE), "--resolution", str(RES), "--samples",
                           "16"], capture_output=True, text=True)
    assert proc.returncode == 2 and "--inplane-by rendered" in proc.stderr and "Traceback" not in proc.stderr
    assert len(read_index(folder)) == 5


def test_a_set_denoised_the_older_way_is_used_whole_and_never_resumed(both_sets, tmp_path):
    """Sets record their denoiser prefilter (`fast` since issue 36); one from before the record (`accurate`)
    is read as it is when complete, and half of one is refused in one line, nothing added."""
    _, rotated = both_sets
    assert {r["denoise_prefilter"] for r in read_index(rotated).values()} == {"fast"}
    out = tmp_path / "older"
    folder = set_dir(out, "robotiq_2f85", VIEWS, INPLANE, RES)
    shutil.copytree(rotated, folder)
    older = {k: {f: v for f, v in rec.items() if f != "denoise_prefilter"} for k, rec in read_index(folder).items()}
    (folder / "templates.json").write_text(json.dumps(older))
    command = [sys.executable, "-m", "syneepose", "templates", "--out", str(out), "--ee", "robotiq_2f85", "--views",
               str(VIEWS), "--inplane", str(INPLANE), "--resolution", str(RES), "--samples", "16"]
    assert subprocess.run(command, capture_output=True, text=True).returncode == 0
    assert read_index(folder) == older
    (folder / "templates.json").write_text(json.dumps({k: v for k, v in older.items() if int(k) < 5}))
    proc = subprocess.run(command, capture_output=True, text=True)
    assert proc.returncode == 2 and "accurate prefilter" in proc.stderr and "Traceback" not in proc.stderr
    assert len(read_index(folder)) == 5


def test_a_users_urdf_gives_the_templates_and_model_of_its_end_effector(both_sets, assets, tmp_path):
    """`templates --urdf --ee-link`: the part of a robot's URDF below a link, rendered as a user's own
    end-effector. On the assembled UR5e + 2F-85 URDF below ee_mount it is the catalogue's 2F-85: the same
    template poses and images, and the same BOP model (feepe calibrate's --model)."""
    import trimesh

    _, catalogue = both_sets
    urdf = assets / "robots" / "ur5e+robotiq_2f85.urdf"
    args = [sys.executable, "-m", "syneepose", "templates", "--out", str(tmp_path), "--urdf", str(urdf), "--ee-link",
            "ee_mount", "--name", "my_gripper", "--views", str(VIEWS), "--inplane", str(INPLANE), "--resolution",
            str(RES), "--samples", "16"]
    proc = subprocess.run(args, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    own = set_dir(tmp_path, "my_gripper", VIEWS, INPLANE, RES)
    for key in read_index(catalogue):
        a, b = read_template(catalogue, int(key)), read_template(own, int(key))
        np.testing.assert_allclose(a.T_cam_model, b.T_cam_model)
        assert (a.mask == b.mask).mean() >= 0.999 and cv2.PSNR(a.rgb, b.rgb) >= 40.0
    model = trimesh.load(tmp_path / "models" / "my_gripper.ply")
    reference = trimesh.load(assets / "models" / "obj_000002.ply")
    assert np.array_equal(np.sort(model.vertices, 0), np.sort(reference.vertices, 0))
    for bad, words in ((["--ee-link", "tool0"], "--ee-link 'tool0' is not a link of"),
                       (["--ee", "robotiq_2f85"], "with --urdf and --ee-link use --name")):
        cmd = args[:args.index("--ee-link")] + bad + (["--ee-link", "ee_mount"] if "--ee" in bad else [])
        proc = subprocess.run(cmd + ["--out", str(tmp_path / "bad")], capture_output=True, text=True)
        assert proc.returncode == 2 and words in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
        assert not (tmp_path / "bad" / "templates").exists()


def test_the_rasterised_silhouette_is_what_cycles_renders(both_sets):
    """A segment's `mask` is the end-effector's rigid model rasterised (feepe.raster.silhouette), no longer
    rendered: on the templates Cycles rendered one by one (the end-effector alone, so its index pass is that
    silhouette) the raster gives the same pixels but for a few on the outline, where a pixel centre lies on an
    edge."""
    from feepe import raster
    from syneepose import paths
    from syneepose.robots.catalog import load_catalog
    from syneepose.robots.ee_models import load_ee_mesh

    mesh = load_ee_mesh(load_catalog().end_effector("robotiq_2f85"), paths.part_urdf("robotiq_2f85"))
    index = read_index(both_sets[0])
    differing = covered = 0
    for template_id in range(VIEWS * INPLANE):
        template = read_template(both_sets[0], template_id, index)
        mask = raster.silhouette(mesh.vertices, mesh.faces, template.T_cam_model, template.K, template.mask.shape)
        outline = template.mask ^ cv2.erode(template.mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        outline |= cv2.dilate(template.mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~template.mask
        assert not ((mask != template.mask) & ~outline).any()
        differing += (mask != template.mask).sum()
        covered += template.mask.sum()
    assert covered > 0 and differing <= 1e-3 * covered
