"""Render one end-effector's template set (runs inside a worker process)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from syneepose import templates as T
from syneepose.blender import scene as bscene
from syneepose.blender.exr import linear_to_srgb8
from syneepose.bop import write_atomic, write_png
from syneepose.robots.ee_models import rigid_mesh
from syneepose.robots.kinematics import Kinematics
from syneepose.robots.model import read_urdf

DEPTH_SCALE = 0.1  # mm per PNG unit, as in the data set


def render_templates(ee, part_urdf: Path, folder: Path, n_views: int, n_inplane: int, resolution: int,
                     samples: int, device: str = "cpu", progress=None) -> int:
    """Render the templates not yet on disk; returns how many were rendered."""
    folder = Path(folder)
    index_path = folder / "templates.json"
    index = T.read_index(folder) if index_path.is_file() else {}
    model = read_urdf(part_urdf)
    canonical = dict(ee.canonical)
    mesh = rigid_mesh(model, Path(part_urdf).parent, canonical)
    center = mesh.bounds.mean(0)
    radius = float(np.linalg.norm(mesh.vertices - center, axis=1).max())
    K = T.intrinsics(resolution)
    todo = [(i, v, k, pose) for i, (v, k, pose) in enumerate(T.poses(n_views, n_inplane, center, radius))
            if str(i) not in index]
    if not todo:
        return 0
    for sub in ("rgb", "depth", "mask"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    bscene.reset(resolution, resolution, samples, denoise=samples >= 4, world_color=(1.0, 1.0, 1.0),
                 world_strength=1.0, transparent=True, device=device)
    bscene.set_camera(K, resolution, resolution, np.eye(4))
    objects = bscene.RobotObjects(model, Path(part_urdf).parent, {lk.name for lk in model.links})
    objects.pose(Kinematics(model).link_poses(canonical))
    for i, view, inplane, T_cam_model in todo:
        bscene.move_camera(np.linalg.inv(T_cam_model))
        out = bscene.render(folder)
        mask = out["ee_index"] == bscene.PASS_EE
        depth = np.where(mask, out["ee_depth"], 0.0)
        name = f"{i:06d}.png"
        write_png(folder / "rgb" / name, linear_to_srgb8(out["rgb_linear"])[..., ::-1])
        write_png(folder / "depth" / name, np.round(depth * 1000.0 / DEPTH_SCALE).astype(np.uint16))
        write_png(folder / "mask" / name, mask.astype(np.uint8) * 255)
        index[str(i)] = {"view": view, "inplane": inplane, "cam_K": K.ravel().tolist(),
                         "T_cam_model": T_cam_model.tolist(), "depth_scale": DEPTH_SCALE, "obj_id": ee.obj_id,
                         "samples": samples}
        write_atomic(index_path, json.dumps(index, indent=2, sort_keys=True).encode())
        if progress is not None:
            progress(1)
    return len(todo)
