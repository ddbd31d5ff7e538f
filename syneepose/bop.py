"""BOP "scenewise" writer and reader: one video segment = one BOP scene, plus our robot sidecar
`scene_robot.json`. Every file goes to a temp name and is `os.replace`d, so a killed run leaves only
whole files and a new writer resumes the scene frame by frame."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from syneepose.errors import UserError
from syneepose.transforms import make_T

GT_ID = 0  # one object (the end-effector) per frame
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


@dataclass
class SceneMeta:
    obj_id: int
    arm: str
    end_effector: str
    joint_names: list[str]
    T_cam_base: np.ndarray  # (4, 4) metres, static in a segment; the BOP world frame is the robot base
    depth_scale: float = 0.1  # mm per depth PNG unit
    marker: dict | None = None  # MarkerBoard.to_json() when a ChArUco board rides on the end-effector
    depth_sensor: dict | None = None  # {"mode": "stereo" | "both", "profile": {...}}; None: exact depth


EXTRAS = {"stereo": ("depth_gt",), "both": ("depth_gt", "ir_left", "ir_right")}


def _image_paths(scene_dir: Path, im_id: int, depth_sensor: dict | None = None) -> dict[str, Path]:
    """The files of one frame; a simulated depth sensor adds the exact depth (and the IR pair)."""
    mask_name = f"{im_id:06d}_{GT_ID:06d}.png"
    paths = {"rgb": scene_dir / "rgb" / f"{im_id:06d}.png", "depth": scene_dir / "depth" / f"{im_id:06d}.png",
             "mask": scene_dir / "mask" / mask_name, "mask_visib": scene_dir / "mask_visib" / mask_name}
    for extra in EXTRAS.get((depth_sensor or {}).get("mode"), ()):
        paths[extra] = scene_dir / extra / f"{im_id:06d}.png"
    return paths


def write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def write_png(path: Path, image: np.ndarray) -> None:
    """Encoded in memory: cv2.imwrite picks the format from the extension, which the temp name lacks."""
    _, buf = cv2.imencode(".png", image)
    write_atomic(path, buf.tobytes())


def read_png(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise UserError(f"{path}: not a readable PNG; delete the scene folder and write it again")
    return image


def _floats(a) -> list[float]:
    return np.asarray(a, dtype=float).ravel().tolist()


def _load_records(scene_dir: Path) -> dict[str, dict]:
    paths = {name: scene_dir / f"{name}.json" for name in _JSONS}
    return {name: json.loads(p.read_text()) if p.exists() else {} for name, p in paths.items()}


def _complete(scene_dir: Path, records: dict[str, dict], im_id: int) -> bool:
    key, sensor = str(im_id), records["scene_robot"].get("depth_sensor")
    return (all(key in records[name] for name in _JSONS[:3]) and key in records["scene_robot"].get("frames", {})
            and all(p.exists() for p in _image_paths(scene_dir, im_id, sensor).values()))


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
    """Writes the frames of one scene; a new writer on an existing folder resumes it (skip `done` frames)."""

    def __init__(self, scene_dir: Path, meta: SceneMeta):
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
        self._records["scene_robot"] = {
            "arm": meta.arm, "end_effector": meta.end_effector, "config": f"{meta.arm}+{meta.end_effector}",
            "joint_names": list(meta.joint_names), "T_cam_base": np.asarray(meta.T_cam_base, dtype=float).tolist(),
            "frames": robot.get("frames", {})}
        if meta.marker is not None:
            self._records["scene_robot"]["marker"] = meta.marker
        if meta.depth_sensor is not None:
            self._records["scene_robot"]["depth_sensor"] = meta.depth_sensor
        for path in _image_paths(self.scene_dir, 0, meta.depth_sensor).values():
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

    def write(self, frame: Frame) -> None:
        """Images first, then every JSON, so a JSON record only ever names whole images."""
        meta, key = self.meta, str(frame.im_id)
        depth_png = _depth_png(frame, meta.depth_scale)
        paths = _image_paths(self.scene_dir, frame.im_id, meta.depth_sensor)
        write_png(paths["rgb"], cv2.cvtColor(np.ascontiguousarray(frame.rgb), cv2.COLOR_RGB2BGR))
        write_png(paths["depth"], depth_png)
        for name, image in self._extras(frame, depth_png).items():
            write_png(paths[name], image)
        for name in ("mask", "mask_visib"):
            write_png(paths[name], np.asarray(getattr(frame, name), dtype=bool).astype(np.uint8) * 255)

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
        for name in _JSONS:
            text = json.dumps(records[name], indent=2, sort_keys=True)
            write_atomic(self.scene_dir / f"{name}.json", text.encode())


def scene_dirs(split_dir: Path) -> dict[int, Path]:
    """The scene folders of a split (`<root>/train`) by scene id; empty when the split has none."""
    split_dir = Path(split_dir)
    if not split_dir.is_dir():
        return {}
    return {int(p.name): p for p in sorted(split_dir.iterdir()) if p.is_dir() and p.name.isdigit()}


def read_scene(scene_dir: Path) -> tuple[SceneMeta, list[int]]:
    """The scene's meta and the sorted ids of its complete frames (half-written ones are left out)."""
    scene_dir = Path(scene_dir)
    records = _load_records(scene_dir)
    robot = records["scene_robot"]
    im_ids = sorted(int(k) for k in robot.get("frames", {}) if _complete(scene_dir, records, int(k)))
    if not im_ids:
        raise UserError(f"{scene_dir}: no complete frame (scene_robot.json and BOP files); write the scene first")
    first = str(im_ids[0])
    meta = SceneMeta(obj_id=records["scene_gt"][first][GT_ID]["obj_id"], arm=robot["arm"],
                     end_effector=robot["end_effector"], joint_names=list(robot["joint_names"]),
                     T_cam_base=np.array(robot["T_cam_base"], dtype=float),
                     depth_scale=records["scene_camera"][first]["depth_scale"], marker=robot.get("marker"),
                     depth_sensor=robot.get("depth_sensor"))
    return meta, im_ids


def read_frame(scene_dir: Path, im_id: int) -> Frame:
    """One complete frame back in our units: depth and translations in metres, masks as bool."""
    scene_dir = Path(scene_dir)
    records = _load_records(scene_dir)
    if not _complete(scene_dir, records, im_id):
        raise UserError(f"{scene_dir}: no complete frame {im_id}; `read_scene` lists the frames present")
    key, paths = str(im_id), _image_paths(scene_dir, im_id, records["scene_robot"].get("depth_sensor"))
    camera, gt = records["scene_camera"][key], records["scene_gt"][key][GT_ID]
    robot = records["scene_robot"]["frames"][key]
    extras = {n: read_png(paths[n]) for n in ("ir_left", "ir_right") if n in paths}
    if "depth_gt" in paths:
        extras["depth_gt"] = read_png(paths["depth_gt"]) * (camera["depth_scale"] / 1000.0)
    return Frame(im_id=im_id, rgb=cv2.cvtColor(read_png(paths["rgb"]), cv2.COLOR_BGR2RGB),
                 depth=read_png(paths["depth"]) * (camera["depth_scale"] / 1000.0),
                 mask=read_png(paths["mask"]) > 127, mask_visib=read_png(paths["mask_visib"]) > 127,
                 K=np.array(camera["cam_K"], dtype=float).reshape(3, 3),
                 T_cam_ee=make_T(np.reshape(gt["cam_R_m2c"], (3, 3)), np.array(gt["cam_t_m2c"]) / 1000.0),
                 joint_positions=np.array(robot["joint_positions"], dtype=float),
                 T_base_ee=np.array(robot["T_base_ee"], dtype=float), **extras)
