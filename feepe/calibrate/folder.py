"""A recording as a folder (docs/calibrate.md, "A folder"):

    camera_info.yaml | camera_info.json   intrinsics (k: 9 numbers, or camera_matrix.data, or fx fy cx cy)
                                          and depth_scale: metres per unit of the depth PNGs (default 0.001)
    rgb/<frame>.png|.jpg                  colour images
    depth/<frame>.png | <frame>.tiff      depth registered to the colour image: 16-bit PNG in depth_scale units,
                                          or 32-bit float TIFF in metres (optional: an RGB camera)
    masks/<frame>.png                     the end-effector's mask, nonzero inside (optional)
    joint_states.csv                      a header `frame,<joint name>,...`, one row per frame (rad, m)
    joint_states.json                     or {"<frame>": {"<joint name>": position, ...}}
    flange_poses.json                     or {"<frame>": 4x4 pose of the end-effector link in the base, m}
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import yaml

from feepe.calibrate.recording import RecordedFrame, Recording, intrinsics
from kernel.errors import UserError
from kernel.files import write_atomic, write_png

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def read_folder(root: Path) -> Recording:
    root = Path(root)
    info = _camera_info(root)
    K, width, height = intrinsics(info, str(root / "camera_info"))
    scale = float(info.get("depth_scale", 0.001))
    images = {p.stem: p for p in sorted((root / "rgb").glob("*")) if p.suffix.lower() in IMAGE_SUFFIXES}
    if not images:
        raise UserError(f"{root / 'rgb'}: no colour images (.png, .jpg); see docs/calibrate.md for a recording's folder")
    joints, poses, source = _robot_states(root)
    known = set(joints or poses)
    missing = [name for name in images if name not in known]
    if missing:
        raise UserError(f"{source}: no row for frame(s) {', '.join(missing[:5])}"
                        f"{' ...' if len(missing) > 5 else ''}; give the robot's state for every image in rgb/")
    has_depth = (root / "depth").is_dir()

    def read():
        for i, (name, path) in enumerate(images.items()):
            rgb = _image(path, cv2.IMREAD_COLOR)[..., ::-1].copy()
            if width and height and rgb.shape[:2] != (height, width):
                raise UserError(f"{path}: {rgb.shape[1]}x{rgb.shape[0]}, camera_info says {width}x{height}")
            depth = _depth(root / "depth", name, scale) if has_depth else None
            mask_path = root / "masks" / f"{name}.png"
            mask = _image(mask_path, cv2.IMREAD_GRAYSCALE) > 0 if mask_path.is_file() else None
            yield RecordedFrame(name, float(i), rgb, depth, K, joints[name] if joints is not None else None,
                                None if poses is None else poses[name], mask)

    return Recording(str(root), len(images), read)


def _camera_info(root: Path) -> dict:
    for name in ("camera_info.yaml", "camera_info.yml", "camera_info.json"):
        path = root / name
        if path.is_file():
            try:
                found = json.loads(path.read_text()) if path.suffix == ".json" else yaml.safe_load(path.read_text())
            except (ValueError, yaml.YAMLError) as exc:
                raise UserError(f"{path}: not readable ({str(exc).splitlines()[0]})") from None
            if not isinstance(found, dict):
                raise UserError(f"{path}: expected a mapping with the intrinsics")
            return found
    if not root.is_dir():
        raise UserError(f"{root}: no such folder or bag")
    raise UserError(f"{root}: no camera_info.yaml or camera_info.json with the intrinsics")


def _robot_states(root: Path) -> tuple[dict | None, dict | None, Path]:
    """Joint positions or flange poses by frame name, and the file they came from."""
    csv_path, json_path = root / "joint_states.csv", root / "flange_poses.json"
    if csv_path.is_file():
        with csv_path.open(newline="") as f:
            rows = list(csv.DictReader(f))
        if not rows or "frame" not in rows[0]:
            raise UserError(f"{csv_path}: expected a header `frame,<joint name>,...` and one row per frame")
        try:
            return {row["frame"]: {k: float(v) for k, v in row.items() if k != "frame"} for row in rows}, None, csv_path
        except (TypeError, ValueError) as exc:
            raise UserError(f"{csv_path}: a joint position is not a number ({exc})") from None
    joints_json = root / "joint_states.json"
    if joints_json.is_file():
        try:
            found = json.loads(joints_json.read_text())
            return ({str(name): {k: float(v) for k, v in joints.items()} for name, joints in found.items()}, None,
                    joints_json)
        except (ValueError, TypeError, AttributeError) as exc:
            raise UserError(f"{joints_json}: expected {{\"<frame>\": {{\"<joint>\": position}}}} ({exc})") from None
    if json_path.is_file():
        try:
            poses = {name: np.asarray(T, float) for name, T in json.loads(json_path.read_text()).items()}
        except (ValueError, TypeError, AttributeError) as exc:
            raise UserError(f"{json_path}: expected {{\"<frame>\": 4x4 matrix}} ({exc})") from None
        bad = [name for name, T in poses.items() if T.shape != (4, 4)]
        if bad:
            raise UserError(f"{json_path}: frame {bad[0]} is not a 4x4 matrix")
        return None, poses, json_path
    raise UserError(f"{root}: no joint_states.csv, joint_states.json or flange_poses.json: the robot's state per "
                    "frame is needed")


def _depth(folder: Path, name: str, scale: float) -> np.ndarray:
    tiff = folder / f"{name}.tiff"
    if tiff.is_file():
        return _image(tiff, cv2.IMREAD_UNCHANGED).astype(float)
    return _image(folder / f"{name}.png", cv2.IMREAD_UNCHANGED) * scale


class FolderWriter:
    """Writes frames as a recording folder, as they are read (the calibration's saved samples: solved
    again with other options, the bag is not read again). Depth as float TIFF, the metres as read, or with
    `depth_scale` (metres per unit) as 16-bit PNG."""

    def __init__(self, root: Path, depth_scale: float | None = None):
        self.root, self.rows, self.poses, self.K, self.size = Path(root), [], {}, None, None
        self.depth_scale = depth_scale
        for sub in ("rgb", "depth", "masks"):
            (self.root / sub).mkdir(parents=True, exist_ok=True)

    def add(self, frame: RecordedFrame) -> None:
        write_png(self.root / "rgb" / f"{frame.name}.png", frame.rgb[..., ::-1])
        if frame.depth is not None and self.depth_scale:
            write_png(self.root / "depth" / f"{frame.name}.png", np.round(frame.depth / self.depth_scale).astype(np.uint16))
        elif frame.depth is not None:
            _, data = cv2.imencode(".tiff", frame.depth.astype(np.float32))
            write_atomic(self.root / "depth" / f"{frame.name}.tiff", data.tobytes())
        if frame.mask is not None:
            write_png(self.root / "masks" / f"{frame.name}.png", frame.mask.astype(np.uint8) * 255)
        if frame.joints is not None:
            self.rows.append((frame.name, frame.joints))
        else:
            self.poses[frame.name] = np.asarray(frame.T_base_ee).tolist()
        self.K, self.size = frame.K, frame.rgb.shape[:2]

    def close(self) -> None:
        for sub in ("depth", "masks"):
            if not any((self.root / sub).iterdir()):
                (self.root / sub).rmdir()
        info = {"k": np.asarray(self.K).reshape(-1).tolist(), "width": int(self.size[1]), "height": int(self.size[0]),
                **({"depth_scale": self.depth_scale} if self.depth_scale else {})}
        write_atomic(self.root / "camera_info.yaml", yaml.safe_dump(info).encode())
        if self.rows:
            names = list(self.rows[0][1])
            text = "\n".join([",".join(["frame", *names])] + [",".join([n, *(repr(float(q[j])) for j in names)])
                                                                for n, q in self.rows])
            write_atomic(self.root / "joint_states.csv", (text + "\n").encode())
        else:
            write_atomic(self.root / "flange_poses.json", json.dumps(self.poses).encode())


def _image(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise UserError(f"{path}: missing or not an image")
    return image
