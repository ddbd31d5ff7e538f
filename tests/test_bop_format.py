"""The data set as BOP tools read it (docs/bop_datasets_format.md of bop_toolkit): frame keys in integer order,
scene_gt_coco.json that pycocotools decodes back to the visible masks, the root files (camera.json, test
targets) over every scene, the same whatever the order of the runs that wrote them; the `test` split."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO

from kernel import bop
from kernel.bop import Frame, SceneMeta, SceneWriter, split_dir, split_name, write_root_files
from kernel.errors import UserError
from kernel.transforms import make_T
from syneepose import jobs
from syneepose.preset import load_preset
from syneepose.robots.catalog import load_catalog
from syneepose.scene.spec import RenderSettings

H, W, FRAMES = 12, 16, 12  # 12 frames: keys "10" and "11" sort before "2" as strings
K = np.array([[20.0, 0.0, 7.5], [0.0, 20.0, 5.5], [0.0, 0.0, 1.0]])
SCENE_JSONS = ("scene_camera", "scene_gt", "scene_gt_info", "scene_gt_coco", "scene_robot")
OBJ_IDS = sorted(ee.obj_id for ee in load_catalog().end_effectors.values())  # as the renderer passes them


def _meta(obj_id=2) -> SceneMeta:
    return SceneMeta(obj_id=obj_id, arm="ur5e", end_effector="robotiq_2f85", joint_names=["j0", "j1"],
                     T_cam_base=make_T(np.eye(3), [0.1, 0.2, 1.5]))


def _frame(im_id: int) -> Frame:
    """Random images and a random blob; frame 3 is 5 % visible (below BOP's 10 %), frame 4 fully hidden."""
    rng = np.random.default_rng(im_id)
    mask = np.zeros((H, W), bool)
    mask[rng.integers(0, 4):rng.integers(6, H), rng.integers(0, 5):rng.integers(8, W)] = True
    mask_visib = mask & (rng.random((H, W)) < 0.7)
    if im_id == 3:
        mask[:] = True
        mask_visib = np.zeros((H, W), bool)
        mask_visib[:2, :5] = True  # 10 of 192 pixels
    if im_id == 4:
        mask_visib = np.zeros((H, W), bool)
    return Frame(im_id=im_id, rgb=rng.integers(0, 256, (H, W, 3), dtype=np.uint8), depth=rng.uniform(0.5, 2, (H, W)),
                 mask=mask, mask_visib=mask_visib, K=K, T_cam_ee=make_T(np.eye(3), [0.0, 0.0, 0.8 + im_id / 100]),
                 joint_positions=rng.uniform(-2, 2, 2), T_base_ee=np.eye(4))


def _write(scene_dir, im_ids, obj_id=2):
    writer = SceneWriter(scene_dir, _meta(obj_id), OBJ_IDS)
    for im_id in im_ids:
        writer.write(_frame(im_id))


def _dataset(root, scenes=(0, 1), split="test"):
    root.mkdir(parents=True, exist_ok=True)
    (root / "dataset_info.json").write_text(json.dumps({"split": split}))
    for scene_id in scenes:
        _write(root / split / f"{scene_id:06d}", range(FRAMES), obj_id=scene_id + 1)
    return root


def _load(path):
    return json.loads(path.read_text())


def test_frame_keys_in_integer_order_and_bop_units(tmp_path):
    scene = tmp_path / "000000"
    _write(scene, range(FRAMES))
    keys = [str(i) for i in range(FRAMES)]
    for name in ("scene_camera", "scene_gt", "scene_gt_info"):
        assert list(_load(scene / f"{name}.json")) == keys, name
    assert list(_load(scene / "scene_robot.json")["frames"]) == keys
    camera, gt, info = (_load(scene / f"{n}.json")["5"] for n in ("scene_camera", "scene_gt", "scene_gt_info"))
    assert len(camera["cam_K"]) == 9 and all(isinstance(v, float) for v in camera["cam_K"])
    assert camera["depth_scale"] == 0.1 and len(camera["cam_R_w2c"]) == 9
    assert camera["cam_t_w2c"] == pytest.approx([100.0, 200.0, 1500.0])  # mm
    assert gt[0]["obj_id"] == 2 and len(gt[0]["cam_R_m2c"]) == 9
    assert gt[0]["cam_t_m2c"] == pytest.approx([0.0, 0.0, 850.0])  # mm
    assert all(isinstance(v, int) for v in info[0]["bbox_obj"] + info[0]["bbox_visib"])
    depth = cv2.imread(str(scene / "depth" / "000005.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and np.abs(depth * 0.1 - _frame(5).depth * 1000).max() <= 0.05 + 1e-9


def test_scene_gt_coco_decodes_to_the_visible_masks(tmp_path):
    scene = tmp_path / "000000"
    _write(scene, range(FRAMES))
    coco = _load(scene / "scene_gt_coco.json")
    assert [im["id"] for im in coco["images"]] == list(range(FRAMES))
    assert coco["images"][7] == {"id": 7, "file_name": "rgb/000007.png", "width": W, "height": H}
    assert coco["categories"] == [{"id": i, "name": str(i), "supercategory": "syneepose"} for i in range(1, 7)]
    annotations = {a["image_id"]: a for a in coco["annotations"]}
    assert 4 not in annotations  # nothing visible: an image without annotation, as calc_gt_coco.py skips it
    assert [a["id"] for a in coco["annotations"]] == list(range(1, FRAMES))
    for im_id, ann in annotations.items():
        frame = _frame(im_id)
        decoded = mask_utils.decode(mask_utils.frPyObjects(ann["segmentation"], H, W))
        assert decoded.dtype == np.uint8 and np.array_equal(decoded.astype(bool), frame.mask_visib), im_id
        ys, xs = np.nonzero(frame.mask)  # the amodal box, COCO's inclusive width as the toolkit's
        assert ann["bbox"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
        assert ann["area"] == frame.mask_visib.sum() and ann["category_id"] == 2 and ann["iscrowd"] == 0
        assert ann["ignore"] == (im_id == 3)
        # pycocotools' own encoding of the mask is the same RLE
        assert mask_utils.frPyObjects(ann["segmentation"], H, W)["counts"] == \
            mask_utils.encode(np.asfortranarray(frame.mask_visib.astype(np.uint8)))["counts"]
    api = COCO(str(scene / "scene_gt_coco.json"))
    assert np.array_equal(api.annToMask(api.loadAnns(api.getAnnIds(imgIds=[6]))[0]).astype(bool), _frame(6).mask_visib)


def test_rle_starts_with_a_background_run():
    mask = np.zeros((3, 2), bool)
    mask[0, 0] = mask[2, 1] = True
    assert bop._rle(mask) == {"counts": [0, 1, 4, 1], "size": [3, 2]}
    assert bop._rle(np.zeros((2, 2), bool)) == {"counts": [4], "size": [2, 2]}


def test_resumed_and_backfilled_scenes_write_the_same_files(tmp_path):
    whole, resumed, old = tmp_path / "whole", tmp_path / "resumed", tmp_path / "old"
    _write(whole, range(5))
    _write(resumed, range(3))
    _write(resumed, range(3, 5))
    _write(old, range(3))
    (old / "scene_gt_coco.json").unlink()  # a scene written before scene_gt_coco.json existed
    _write(old, range(3, 5))
    for name in SCENE_JSONS:
        text = (whole / f"{name}.json").read_text()
        assert (resumed / f"{name}.json").read_text() == text and (old / f"{name}.json").read_text() == text, name


def test_root_files_list_every_complete_frame(tmp_path):
    root = _dataset(tmp_path / "set")
    scene = root / "test" / "000001"
    (scene / "rgb" / "000011.png").unlink()  # an incomplete frame is no target
    write_root_files(root, K, W, H)
    camera = _load(root / "camera.json")
    rgb = cv2.imread(str(root / "test" / "000000" / "rgb" / "000000.png"))
    assert (camera["height"], camera["width"]) == rgb.shape[:2]
    assert camera["depth_scale"] == _load(scene / "scene_camera.json")["0"]["depth_scale"]
    assert (camera["fx"], camera["fy"], camera["cx"], camera["cy"]) == (20.0, 20.0, 7.5, 5.5)
    bop24 = _load(root / "test_targets_bop24.json")
    assert bop24 == [{"im_id": i, "scene_id": 0} for i in range(FRAMES)] + \
        [{"im_id": i, "scene_id": 1} for i in range(FRAMES - 1)]
    bop19 = _load(root / "test_targets_bop19.json")
    # frames 3 (5 % visible) and 4 (hidden) are under enumerate_test_targets.py's 10 %
    assert bop19 == [{"im_id": t["im_id"], "inst_count": 1, "obj_id": t["scene_id"] + 1, "scene_id": t["scene_id"]}
                     for t in bop24 if t["im_id"] not in (3, 4)]
    assert all(list(t) == ["im_id", "inst_count", "obj_id", "scene_id"] for t in bop19)


def test_root_files_do_not_depend_on_the_order_of_runs(tmp_path):
    full = _dataset(tmp_path / "full")
    write_root_files(full, K, W, H)
    shards = _dataset(tmp_path / "shards", scenes=(1,))
    write_root_files(shards, K, W, H)  # the first shard ends before the other scene exists
    _write(shards / "test" / "000000", range(5), obj_id=1)
    write_root_files(shards, K, W, H)  # a killed run ...
    _write(shards / "test" / "000000", range(FRAMES), obj_id=1)
    write_root_files(shards, K, W, H)  # ... resumed
    for name in ("camera.json", "test_targets_bop19.json", "test_targets_bop24.json"):
        assert (shards / name).read_text() == (full / name).read_text(), name


def test_readers_take_the_split_from_dataset_info(tmp_path):
    assert split_name(tmp_path) == "train"  # data sets from before dataset_info.json recorded the split
    (tmp_path / "dataset_info.json").write_text(json.dumps({"preset": "mini"}))
    assert split_dir(tmp_path) == tmp_path / "train"
    (tmp_path / "dataset_info.json").write_text(json.dumps({"split": "test"}))
    assert split_dir(tmp_path) == tmp_path / "test"


def _plan(out):
    content = jobs.SceneContent(load_preset("mini"), "mini", seed=0)
    return jobs.make_jobs(content, RenderSettings(W, H, 1), jobs.SegmentSelection(("panda+panda_hand",), 1), out, out)


def test_dataset_info_names_the_test_split_and_copies_models_eval_when_built(tmp_path):
    assets, out = tmp_path / "assets", tmp_path / "out"
    (assets / "models").mkdir(parents=True)
    (assets / "models" / "obj_000001.ply").write_text("ply")
    out.mkdir()
    jobs.write_dataset_info(out, _plan(out), assets)
    info = _load(out / "dataset_info.json")
    assert (info["name"], info["split"]) == ("syneepose", "test") and bop.SPLIT == "test"
    assert (out / "models" / "obj_000001.ply").is_file() and not (out / "models_eval").exists()
    assert _plan(out).jobs[0].scene_dir == out / "test" / "000000"
    (assets / "models_eval").mkdir()
    (assets / "models_eval" / "obj_000001.ply").write_text("eval ply")
    jobs.write_dataset_info(out, _plan(out), assets)
    assert (out / "models_eval" / "obj_000001.ply").read_text() == "eval ply"
    assert not [p for p in out.iterdir() if ".tmp" in p.name]


def test_a_full_disk_while_copying_the_models_leaves_no_half_folder(tmp_path, monkeypatch):
    import errno
    import shutil

    assets, out = tmp_path / "assets", tmp_path / "out"
    (assets / "models").mkdir(parents=True)
    (assets / "models" / "obj_000001.ply").write_text("ply")
    out.mkdir()

    def full(src, dst, **kw):
        Path(dst).mkdir()
        (Path(dst) / "obj_000001.ply").write_text("pl")
        raise OSError(errno.ENOSPC, "No space left on device", str(dst))

    plan = _plan(out)
    monkeypatch.setattr(shutil, "copytree", full)
    with pytest.raises(UserError, match="No space left on device.*free space"):
        jobs.write_dataset_info(out, plan, assets)
    assert sorted(p.name for p in out.iterdir()) == ["dataset_info.json"]


def test_resuming_a_train_data_set_is_refused(tmp_path):
    out = tmp_path / "old"
    out.mkdir()
    (out / "dataset_info.json").write_text(json.dumps({"split": "train", "configurations": ["ur5e+robotiq_2f85"]}))
    plan = _plan(out)
    with pytest.raises(UserError) as err:
        jobs.write_dataset_info(out, plan, tmp_path)
    assert str(out) in str(err.value) and "another --out" in str(err.value) and "\n" not in str(err.value)
    assert _load(out / "dataset_info.json")["split"] == "train"
    # a worker started by an older main process writes where that process's dataset_info.json says
    assert plan.jobs[0].scene_dir == out / "train" / "000000"


def test_camera_json_is_the_presets_nominal_camera(tmp_path):
    root = _dataset(tmp_path / "set", scenes=(0,))
    jobs.write_root_files(root, load_preset("mini"), 320, 240)  # hfov 50-70 deg, principal point jittered
    camera = _load(root / "camera.json")
    assert camera["fx"] == camera["fy"] == pytest.approx(160 / np.tan(np.deg2rad(30)))
    assert (camera["cx"], camera["cy"], camera["width"], camera["height"]) == (159.5, 119.5, 320, 240)

