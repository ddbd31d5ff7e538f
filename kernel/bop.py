"""BOP "scenewise" writer and reader: one video segment = one BOP scene, plus our robot sidecar
`scene_robot.json`. Every file goes to a temp name and is `os.replace`d, so a killed run leaves only
whole files and a new writer resumes the scene frame by frame. The data set's root files (camera.json,
test_targets_bop19/24.json) are derived from the scenes present, so any order of runs ends the same."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from kernel.errors import UserError
from kernel.files import read_json, read_png, write_atomic, write_json, write_png
from kernel.transforms import make_T

GT_ID = 0  # one object (the end-effector) per frame
DEPTH_SCALE = 0.1  # mm per depth PNG unit
MAX_DEPTH = 65535 * DEPTH_SCALE / 1000.0  # metres: the uint16 depth PNG's range at DEPTH_SCALE
MIN_VISIB_FRACT = 0.1  # bop_toolkit's threshold for a test target (enumerate_test_targets) and COCO `ignore`
# scene_robot last: a frame's sidecar record exists only once its BOP records do.
_JSONS = ("scene_camera", "scene_gt", "scene_gt_info", "scene_robot")


@dataclass
class Frame:
    im_id: int
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float, metres, 0 where no depth
    mask: np.ndarray  # (H, W) bool, full silhouette of the end-effector
    mask_visib: np.ndarray  # (H, W) bool
    K: np.ndarray  # (3, 3)
    T_cam_ee: np.ndarray  # (4, 4) metres
    joint_positions: np.ndarray  # (n,)
    T_base_ee: np.ndarray  # (4, 4) metres
    depth_gt: np.ndarray | None = None  # exact depth when `depth` is a simulated sensor's (metres)
    ir_left: np.ndarray | None = None  # (h, w) uint8 IR pair of the stereo sensor (--depth both)
    ir_right: np.ndarray | None = None
    link_ids: np.ndarray | None = None  # (H, W) uint8 visible robot part: 0 none, k + 1 = SceneMeta.links[k]


@dataclass
class SceneMeta:
    obj_id: int
    arm: str
    end_effector: str
    joint_names: list[str]
    T_cam_base: np.ndarray  # (4, 4) metres, static in a segment; the BOP world frame is the robot base
    depth_scale: float = DEPTH_SCALE
    marker: dict | None = None  # MarkerBoard.to_json() when a ChArUco board rides on the end-effector
    depth_sensor: dict | None = None  # {"mode": "stereo" | "both", "profile": {...}}; None: exact depth
    links: list[str] | None = None  # robot parts of `robot_mask_visib/` (arm links, then the end-effector)
    settings: dict | None = None  # what rendered the frames (seed, preset, resolution, ...); a resume must match
    dropped_distractors: int = 0  # objects sampled for the scene but left out: no place away from the robot found


# The split renders write: BOP methods (SAM-6D, FoundationPose, MegaPose) and bop_toolkit's eval scripts read
# `test` + test_targets.
SPLIT = "test"
DATASET_INFO = "dataset_info.json"  # our record at the root of what rendered the data set
# a scene's per-frame image folders, named as BOP names them (`frame_paths` keys their files by Frame's fields)
RGB_DIR, DEPTH_DIR, MASK_DIR, MASK_VISIB_DIR = "rgb", "depth", "mask", "mask_visib"
DEPTH_GT_DIR = "depth_gt"  # the exact depth beside a simulated sensor's in depth/
EXTRAS = {"stereo": (DEPTH_GT_DIR,), "both": (DEPTH_GT_DIR, "ir_left", "ir_right")}
LINK_IDS_DIR = "robot_mask_visib"  # our sidecar, not BOP: which robot part each pixel sees (uint8 PNG)


def image_path(scene_dir: Path, folder: str, im_id: int) -> Path:
    """A frame's image in one of the scene's per-frame folders, named by the frame id as BOP names them."""
    return Path(scene_dir) / folder / f"{im_id:06d}.png"


def object_mask_path(scene_dir: Path, folder: str, im_id: int) -> Path:
    """A frame's mask of the end-effector (BOP's ground-truth object GT_ID) in `folder` (mask/, mask_visib/)."""
    return Path(scene_dir) / folder / f"{im_id:06d}_{GT_ID:06d}.png"


def record_paths(scene_dir: Path) -> dict[str, Path]:
    """The scene's JSON records that the readers load, by name (scene_gt_coco.json is written, never read)."""
    return {name: Path(scene_dir) / f"{name}.json" for name in _JSONS}


def frame_paths(scene_dir: Path, im_id: int, robot: dict | None = None) -> dict[str, Path]:
    """The files of one frame, from the scene's `scene_robot.json` record: a simulated depth sensor adds the
    exact depth (and the IR pair), a scene that names its robot parts adds their visible-mask image.
    `read_frame` reads every one of them."""
    robot = robot or {}
    paths = {"rgb": image_path(scene_dir, RGB_DIR, im_id), "depth": image_path(scene_dir, DEPTH_DIR, im_id),
             "mask": object_mask_path(scene_dir, MASK_DIR, im_id),
             "mask_visib": object_mask_path(scene_dir, MASK_VISIB_DIR, im_id)}
    for extra in EXTRAS.get((robot.get("depth_sensor") or {}).get("mode"), ()):
        paths[extra] = image_path(scene_dir, extra, im_id)
    if robot.get("links"):
        paths["link_ids"] = image_path(scene_dir, LINK_IDS_DIR, im_id)
    return paths


def _floats(a) -> list[float]:
    return np.asarray(a, dtype=float).ravel().tolist()


def read_dataset_info(root: Path) -> dict:
    """The data set's dataset_info.json ({} for a folder without one)."""
    path = Path(root) / DATASET_INFO
    return read_json(path, "restore it, or render into another --out") if path.is_file() else {}


def _load_records(scene_dir: Path) -> dict[str, dict]:
    paths = record_paths(scene_dir)
    records = {name: read_json(p) if p.exists() else {} for name, p in paths.items()}
    _check_fields(paths, records)
    return records


# what the readers take from each frame's record: field -> number of values
_CAMERA_FIELDS = {"cam_K": 9, "depth_scale": 1}
_GT_FIELDS = {"obj_id": 1, "cam_R_m2c": 9, "cam_t_m2c": 3}


def _check_fields(paths: dict[str, Path], records: dict[str, dict]) -> None:
    """Every frame record holds the fields the readers use, as numbers of the right count: a hand-edited or
    foreign file is named with its frame and field, not met later as a KeyError."""
    def bad(name: str, key: str, field: str) -> UserError:
        return UserError(f"{paths[name]}: frame {key} has no usable {field!r}; restore the file or delete the "
                         "scene folder and write it again")

    def numbers(value, count: int) -> bool:
        flat = np.ravel(np.asarray(value, dtype=object)) if isinstance(value, list) else [value]
        return len(flat) == count and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in flat)

    for key, rec in records["scene_camera"].items():
        for field, count in _CAMERA_FIELDS.items():
            if not isinstance(rec, dict) or not numbers(rec.get(field), count):
                raise bad("scene_camera", key, field)
    for key, recs in records["scene_gt"].items():
        for field, count in _GT_FIELDS.items():
            if not isinstance(recs, list) or not recs or not isinstance(recs[GT_ID], dict) \
                    or not numbers(recs[GT_ID].get(field), count):
                raise bad("scene_gt", key, field)
    robot = records["scene_robot"]
    frames = robot.get("frames", {})
    if not isinstance(frames, dict):
        raise UserError(f"{paths['scene_robot']}: 'frames' is not an object of frames; delete the scene folder "
                        "and write it again")
    missing = [f for f in ("arm", "end_effector", "joint_names", "T_cam_base") if frames and f not in robot]
    if missing:
        raise UserError(f"{paths['scene_robot']}: no {missing[0]!r}; restore the file or delete the scene folder "
                        "and write it again")
    for key, rec in frames.items():
        if not isinstance(rec, dict) or not numbers(rec.get("T_base_ee"), 16):
            raise bad("scene_robot", key, "T_base_ee")
        if not isinstance(rec.get("joint_positions"), list):
            raise bad("scene_robot", key, "joint_positions")


def _complete(scene_dir: Path, records: dict[str, dict], im_id: int) -> bool:
    key, robot = str(im_id), records["scene_robot"]
    return (all(key in records[name] for name in _JSONS[:3]) and key in robot.get("frames", {})
            and all(p.exists() for p in frame_paths(scene_dir, im_id, robot).values()))


def complete_frames(scene_dir: Path, records: dict[str, dict] | None = None) -> list[int]:
    """Sorted ids of the scene's complete frames (half-written ones are left out); [] for none."""
    scene_dir = Path(scene_dir)
    records = _load_records(scene_dir) if records is None else records
    return sorted(int(k) for k in records["scene_robot"].get("frames", {}) if _complete(scene_dir, records, int(k)))


def _bbox(mask: np.ndarray) -> list[int]:
    """bop_toolkit's `calc_2d_bbox` on the mask pixels: w = x_max - x_min (no +1), as in the BOP datasets."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()), int(ys.max() - ys.min())]


def gt_info(mask: np.ndarray, mask_visib: np.ndarray, depth: np.ndarray) -> dict:
    """The scene_gt_info record from the rendered masks; depth only matters as > 0 (valid)."""
    mask, mask_visib = np.asarray(mask, dtype=bool), np.asarray(mask_visib, dtype=bool)
    px_all, px_visib = int(mask.sum()), int(mask_visib.sum())
    return {"bbox_obj": _bbox(mask), "bbox_visib": _bbox(mask_visib), "px_count_all": px_all,
            "px_count_valid": int((mask & (np.asarray(depth) > 0)).sum()), "px_count_visib": px_visib,
            "visib_fract": px_visib / px_all if px_all else 0.0}


def _rle(mask: np.ndarray) -> dict:
    """COCO's uncompressed RLE (column-major run lengths, starting with a background run), the form
    bop_toolkit's calc_gt_coco.py and BlenderProc's BOP writer store; pycocotools reads it (frPyObjects)."""
    flat = np.asarray(mask, dtype=bool).ravel(order="F")
    edges = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    runs = np.diff(np.concatenate(([0], edges, [flat.size]))).tolist()
    return {"counts": ([0] if flat[0] else []) + runs, "size": list(mask.shape)}


def _coco_record(im_id: int, obj_id: int, mask: np.ndarray, mask_visib: np.ndarray) -> dict:
    """One frame of scene_gt_coco.json as calc_gt_coco.py makes it: the visible mask as RLE, the amodal box
    of the full mask (COCO's w = x_max - x_min + 1), `ignore` below 10 % visible; no annotation (None)
    when either mask is empty. The annotation id is given when the scene is written out."""
    mask, mask_visib = np.asarray(mask, dtype=bool), np.asarray(mask_visib, dtype=bool)
    height, width = mask.shape
    image = {"id": im_id, "file_name": f"{RGB_DIR}/{im_id:06d}.png", "width": width, "height": height}
    if not mask.any() or not mask_visib.any():
        return {"image": image, "annotation": None}
    x, y, w, h = _bbox(mask)
    area = int(mask_visib.sum())
    return {"image": image, "annotation": {
        "image_id": im_id, "category_id": obj_id, "iscrowd": 0, "area": area, "bbox": [x, y, w + 1, h + 1],
        "segmentation": _rle(mask_visib), "width": width, "height": height,
        "ignore": area / int(mask.sum()) < MIN_VISIB_FRACT}}


def _coco_json(records: dict[int, dict], obj_ids: list[int]) -> dict:
    """scene_gt_coco.json from per-frame records: images in frame order, annotation ids 1, 2, ... and a
    category per object of the data set, as calc_gt_coco.py writes them."""
    frames = [records[i] for i in sorted(records)]
    annotations = [{"id": n, **a} for n, a in enumerate((f["annotation"] for f in frames if f["annotation"]), 1)]
    return {"info": {"description": "syneepose"}, "licenses": [],
            "categories": [{"id": i, "name": str(i), "supercategory": "syneepose"} for i in obj_ids],
            "images": [f["image"] for f in frames], "annotations": annotations}


def _load_coco(scene_dir: Path, records: dict[str, dict]) -> dict[int, dict]:
    """The scene's COCO records by frame; complete frames without one (a scene written before
    scene_gt_coco.json existed) get theirs from the mask PNGs, so a resumed scene lists every frame."""
    path, coco = scene_dir / "scene_gt_coco.json", {}
    if path.exists():
        content = json.loads(path.read_text())
        annotations = {a["image_id"]: {k: v for k, v in a.items() if k != "id"} for a in content["annotations"]}
        coco = {im["id"]: {"image": im, "annotation": annotations.get(im["id"])} for im in content["images"]}
    for key in records["scene_robot"].get("frames", {}):
        im_id = int(key)
        if im_id not in coco and _complete(scene_dir, records, im_id):
            paths = frame_paths(scene_dir, im_id, records["scene_robot"])
            coco[im_id] = _coco_record(im_id, records["scene_gt"][key][GT_ID]["obj_id"],
                                      read_png(paths["mask"]) > 127, read_png(paths["mask_visib"]) > 127)
    return coco


def settings_diff(before: dict, after: dict) -> str:
    """`key old -> new` for each setting that differs, for one-line refusals."""
    keys = [k for k in {**before, **after} if before.get(k) != after.get(k)]
    return ", ".join(f"{k} {before.get(k)} -> {after.get(k)}" for k in keys)


def _depth_png(frame: Frame, depth_scale: float) -> np.ndarray:
    """Checks the frame's images and returns its depth as the uint16 PNG values."""
    shapes = {name: np.shape(getattr(frame, name)) for name in ("rgb", "depth", "mask", "mask_visib")}
    size = shapes["depth"]
    if len(size) != 2 or shapes["rgb"] != (*size, 3) or shapes["mask"] != size or shapes["mask_visib"] != size:
        raise UserError(f"frame {frame.im_id}: image sizes differ: "
                        + ", ".join(f"{name} {shape}" for name, shape in shapes.items())
                        + "; expected rgb (H, W, 3) and the others (H, W)")
    if np.asarray(frame.rgb).dtype != np.uint8:
        raise UserError(f"frame {frame.im_id}: rgb is {np.asarray(frame.rgb).dtype}, expected uint8")
    depth_mm = np.asarray(frame.depth, dtype=float) * 1000.0
    max_mm = 65535 * depth_scale
    if not np.isfinite(depth_mm).all() or depth_mm.min() < 0 or depth_mm.max() > max_mm:
        raise UserError(f"frame {frame.im_id}: depth {np.min(frame.depth):.4g}..{np.max(frame.depth):.4g} m is "
                        f"outside 0..{max_mm / 1000:g} m, the uint16 PNG range at depth_scale {depth_scale}; "
                        "clip the far plane and use 0 for no depth")
    return np.round(depth_mm / depth_scale).astype(np.uint16)


class SceneWriter:
    """Writes the frames of one scene; a new writer on an existing folder resumes it (skip `done` frames).
    `obj_ids`: every object of the data set, the categories of scene_gt_coco.json (as calc_gt_coco.py lists
    them), so each scene names the same categories whichever object it shows."""

    def __init__(self, scene_dir: Path, meta: SceneMeta, obj_ids: list[int]):
        self.scene_dir, self.meta = Path(scene_dir), meta
        self._records = _load_records(self.scene_dir)
        robot = self._records["scene_robot"]
        if robot and (robot["arm"], robot["end_effector"]) != (meta.arm, meta.end_effector):
            raise UserError(f"{self.scene_dir} holds {robot['config']} frames, not "
                            f"{meta.arm}+{meta.end_effector}; write to another folder (a scene never mixes robots)")
        before = (robot.get("depth_sensor") or {}).get("mode", "exact") if robot.get("frames") else None
        after = (meta.depth_sensor or {}).get("mode", "exact")
        if before is not None and before != after:
            raise UserError(f"{self.scene_dir} holds frames with {before} depth, not {after}; write to another "
                            "folder (a scene never mixes depth kinds)")
        if robot.get("frames") and robot.get("links") != meta.links:
            raise UserError(f"{self.scene_dir} holds frames whose robot parts are {robot.get('links')}, not "
                            f"{meta.links} (a render before {LINK_IDS_DIR}/ existed?); write to another folder")
        if robot.get("frames") and meta.settings is not None and robot.get("settings", meta.settings) != meta.settings:
            raise UserError(f"{self.scene_dir} holds frames rendered with other settings "
                            f"({settings_diff(robot['settings'], meta.settings)}); rerun with the same settings "
                            "to resume, or --overwrite to render it again")
        self._records["scene_robot"] = {
            "arm": meta.arm, "end_effector": meta.end_effector, "config": f"{meta.arm}+{meta.end_effector}",
            "joint_names": list(meta.joint_names), "T_cam_base": np.asarray(meta.T_cam_base, dtype=float).tolist(),
            "frames": robot.get("frames", {})}
        if meta.settings is not None:
            self._records["scene_robot"]["settings"] = meta.settings
        if meta.marker is not None:
            self._records["scene_robot"]["marker"] = meta.marker
        if meta.depth_sensor is not None:
            self._records["scene_robot"]["depth_sensor"] = meta.depth_sensor
        if meta.dropped_distractors:
            self._records["scene_robot"]["dropped_distractors"] = meta.dropped_distractors
        if meta.links:
            if len(meta.links) > 255:
                raise UserError(f"{len(meta.links)} robot parts do not fit the uint8 {LINK_IDS_DIR}/ images (255 at most)")
            self._records["scene_robot"]["links"] = list(meta.links)
        self._coco = _load_coco(self.scene_dir, self._records)
        self._obj_ids = sorted(obj_ids)
        for path in frame_paths(self.scene_dir, 0, self._records["scene_robot"]).values():
            path.parent.mkdir(parents=True, exist_ok=True)

    def done(self, im_id: int) -> bool:
        return _complete(self.scene_dir, self._records, im_id)

    def _extras(self, frame: Frame, depth_png: np.ndarray) -> dict[str, np.ndarray]:
        """The PNGs of a simulated sensor's frame: exact depth (same scale as depth/) and the IR pair."""
        names = EXTRAS.get((self.meta.depth_sensor or {}).get("mode"), ())
        missing = [n for n in names if getattr(frame, n) is None]
        if missing:
            raise UserError(f"frame {frame.im_id}: a {self.meta.depth_sensor['mode']} depth scene needs {missing}")
        out = {n: np.asarray(getattr(frame, n), dtype=np.uint8) for n in names if n.startswith("ir_")}
        if "depth_gt" in names:
            out["depth_gt"] = _depth_png(replace(frame, depth=frame.depth_gt), self.meta.depth_scale)
        return out

    def _link_ids(self, frame: Frame, size: tuple[int, int]) -> np.ndarray:
        ids = frame.link_ids
        if ids is None or np.shape(ids) != size:
            raise UserError(f"frame {frame.im_id}: a scene with robot parts {self.meta.links} needs link_ids of "
                            f"shape {size}, got {None if ids is None else np.shape(ids)}")
        ids = np.asarray(ids)
        if ids.min() < 0 or ids.max() > len(self.meta.links):
            raise UserError(f"frame {frame.im_id}: link_ids hold {ids.min()}..{ids.max()}; allowed 0 (no part) "
                            f"to {len(self.meta.links)} (one per robot part)")
        return ids.astype(np.uint8)

    def write(self, frame: Frame) -> None:
        """Images first, then every JSON, so a JSON record only ever names whole images."""
        meta, key = self.meta, str(frame.im_id)
        depth_png = _depth_png(frame, meta.depth_scale)
        paths = frame_paths(self.scene_dir, frame.im_id, self._records["scene_robot"])
        write_png(paths["rgb"], cv2.cvtColor(np.ascontiguousarray(frame.rgb), cv2.COLOR_RGB2BGR))
        write_png(paths["depth"], depth_png)
        for name, image in self._extras(frame, depth_png).items():
            write_png(paths[name], image)
        for name in ("mask", "mask_visib"):
            write_png(paths[name], np.asarray(getattr(frame, name), dtype=bool).astype(np.uint8) * 255)
        if "link_ids" in paths:
            write_png(paths["link_ids"], self._link_ids(frame, depth_png.shape))

        T_cam_base, T_cam_ee = np.asarray(meta.T_cam_base, dtype=float), np.asarray(frame.T_cam_ee, dtype=float)
        records = self._records
        records["scene_camera"][key] = {
            "cam_K": _floats(frame.K), "depth_scale": float(meta.depth_scale),
            "cam_R_w2c": _floats(T_cam_base[:3, :3]), "cam_t_w2c": _floats(T_cam_base[:3, 3] * 1000.0)}
        records["scene_gt"][key] = [{"obj_id": int(meta.obj_id), "cam_R_m2c": _floats(T_cam_ee[:3, :3]),
                                     "cam_t_m2c": _floats(T_cam_ee[:3, 3] * 1000.0)}]
        records["scene_gt_info"][key] = [gt_info(frame.mask, frame.mask_visib, depth_png)]
        records["scene_robot"]["frames"][key] = {
            "joint_positions": _floats(frame.joint_positions),
            "T_base_ee": np.asarray(frame.T_base_ee, dtype=float).tolist()}
        self._coco[frame.im_id] = _coco_record(frame.im_id, meta.obj_id, frame.mask, frame.mask_visib)
        for name in _JSONS[:3]:
            write_json(self.scene_dir / f"{name}.json", records[name])
        write_json(self.scene_dir / "scene_gt_coco.json", _coco_json(self._coco, self._obj_ids), indent=None)
        write_json(self.scene_dir / "scene_robot.json", records["scene_robot"])


def split_name(root: Path) -> str:
    """The split a data set was written to, from its dataset_info.json; "train" for data sets (and
    folders without one) from before renders wrote the BOP `test` split."""
    split = read_dataset_info(root).get("split", "train")
    if not isinstance(split, str):
        raise UserError(f"{Path(root) / DATASET_INFO}: split {split!r} is not a folder name")
    return split


def split_dir(root: Path) -> Path:
    """`<root>/<split>`: the folder holding the data set's scenes."""
    return Path(root) / split_name(root)


def scene_dirs(split_dir: Path) -> dict[int, Path]:
    """The scene folders of a split (`<root>/test`) by scene id; empty when the split has none."""
    split_dir = Path(split_dir)
    if not split_dir.is_dir():
        return {}
    return {int(p.name): p for p in sorted(split_dir.iterdir()) if p.is_dir() and p.name.isdigit()}


def write_root_files(root: Path, K: np.ndarray, width: int, height: int, depth_scale: float = DEPTH_SCALE) -> None:
    """The BOP root files over every complete frame of every scene in the split, whoever wrote it:
    camera.json (the nominal camera `K`; per-frame intrinsics stay in scene_camera.json, as BOP says),
    test_targets_bop19.json (per frame, the objects at least 10 % visible, as enumerate_test_targets.py
    counts them) and test_targets_bop24.json (every frame)."""
    root = Path(root)
    K = np.asarray(K, dtype=float)
    write_json(root / "camera.json", {"cx": K[0, 2], "cy": K[1, 2], "depth_scale": float(depth_scale),
                                      "fx": K[0, 0], "fy": K[1, 1], "height": int(height), "width": int(width)})
    bop19, bop24 = [], []
    for scene_id, scene_dir in scene_dirs(split_dir(root)).items():
        records = _load_records(scene_dir)
        for im_id in complete_frames(scene_dir, records):
            key, counts = str(im_id), {}
            for gt, info in zip(records["scene_gt"][key], records["scene_gt_info"][key]):
                if info["visib_fract"] >= MIN_VISIB_FRACT:
                    counts[gt["obj_id"]] = counts.get(gt["obj_id"], 0) + 1
            bop19 += [{"im_id": im_id, "inst_count": n, "obj_id": obj_id, "scene_id": scene_id}
                      for obj_id, n in sorted(counts.items())]
            bop24.append({"im_id": im_id, "scene_id": scene_id})
    for name, targets in (("test_targets_bop19.json", bop19), ("test_targets_bop24.json", bop24)):
        write_atomic(root / name, ("[\n" + ",\n".join(f"  {json.dumps(t)}" for t in targets) + "\n]").encode())


def read_scene(scene_dir: Path) -> tuple[SceneMeta, list[int]]:
    """The scene's meta and the sorted ids of its complete frames (half-written ones are left out)."""
    scene_dir = Path(scene_dir)
    records = _load_records(scene_dir)
    robot = records["scene_robot"]
    im_ids = complete_frames(scene_dir, records)
    if not im_ids:
        raise UserError(f"{scene_dir}: no complete frame (scene_robot.json and BOP files); write the scene first")
    first = str(im_ids[0])
    meta = SceneMeta(obj_id=records["scene_gt"][first][GT_ID]["obj_id"], arm=robot["arm"],
                     end_effector=robot["end_effector"], joint_names=list(robot["joint_names"]),
                     T_cam_base=np.array(robot["T_cam_base"], dtype=float),
                     depth_scale=records["scene_camera"][first]["depth_scale"], marker=robot.get("marker"),
                     depth_sensor=robot.get("depth_sensor"), links=robot.get("links"), settings=robot.get("settings"),
                     dropped_distractors=robot.get("dropped_distractors", 0))
    return meta, im_ids


def _T_cam_ee(gt: dict) -> np.ndarray:
    """The pose of a scene_gt.json record in metres."""
    return make_T(np.reshape(gt["cam_R_m2c"], (3, 3)), np.array(gt["cam_t_m2c"]) / 1000.0)


def read_gt_poses(scene_dir: Path) -> dict[int, np.ndarray]:
    """T_cam_ee (metres) of every frame in scene_gt.json, without reading any image."""
    gt = json.loads((Path(scene_dir) / "scene_gt.json").read_text())
    return {int(k): _T_cam_ee(v[GT_ID]) for k, v in gt.items()}


def read_frame(scene_dir: Path, im_id: int) -> Frame:
    """One complete frame back in our units: depth and translations in metres, masks as bool."""
    scene_dir = Path(scene_dir)
    records = _load_records(scene_dir)
    if not _complete(scene_dir, records, im_id):
        raise UserError(f"{scene_dir}: no complete frame {im_id}; `read_scene` lists the frames present")
    key, paths = str(im_id), frame_paths(scene_dir, im_id, records["scene_robot"])
    camera, gt = records["scene_camera"][key], records["scene_gt"][key][GT_ID]
    robot = records["scene_robot"]["frames"][key]
    extras = {n: read_png(paths[n]) for n in ("ir_left", "ir_right", "link_ids") if n in paths}
    if "depth_gt" in paths:
        extras["depth_gt"] = read_png(paths["depth_gt"]) * (camera["depth_scale"] / 1000.0)
    return Frame(im_id=im_id, rgb=cv2.cvtColor(read_png(paths["rgb"]), cv2.COLOR_BGR2RGB),
                 depth=read_png(paths["depth"]) * (camera["depth_scale"] / 1000.0),
                 mask=read_png(paths["mask"]) > 127, mask_visib=read_png(paths["mask_visib"]) > 127,
                 K=np.array(camera["cam_K"], dtype=float).reshape(3, 3),
                 T_cam_ee=_T_cam_ee(gt),
                 joint_positions=np.array(robot["joint_positions"], dtype=float),
                 T_base_ee=np.array(robot["T_base_ee"], dtype=float), **extras)
