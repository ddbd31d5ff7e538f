"""Render one end-effector's template set (runs inside a worker process)."""

from __future__ import annotations

from itertools import groupby
from pathlib import Path

import numpy as np

from kernel.template_set import Template, TemplateSetWriter
from syneepose.templates import DENOISE_PREFILTER, intrinsics, poses, roll_template
from syneepose.blender import scene as bscene
from syneepose.colour import linear_to_srgb8
from syneepose.robots.ee_models import rigid_mesh
from syneepose.robots.kinematics import Kinematics
from syneepose.robots.model import RobotModel


def render_templates(model: RobotModel, urdf_dir: Path, canonical: dict[str, float], obj_id: int, folder: Path,
                     n_views: int, n_inplane: int, resolution: int, samples: int, device: str = "cpu",
                     progress=None, inplane: str = "rotated", threads: int = 0) -> int:
    """Render the templates not yet on disk of the end-effector `model` (its links' meshes named relative to
    `urdf_dir`, posed at `canonical`); returns how many were written. `inplane="rotated"` renders each view
    once and rolls the images for its in-plane rotations (roll_template); "rendered" renders every template,
    the reference the rotation is tested against."""
    writer = TemplateSetWriter(folder, obj_id, samples, inplane, DENOISE_PREFILTER)
    mesh = rigid_mesh(model, urdf_dir, canonical)
    centre = mesh.bounds.mean(0)
    radius = float(np.linalg.norm(mesh.vertices - centre, axis=1).max())
    K = intrinsics(resolution)
    planned = list(enumerate(poses(n_views, n_inplane, centre, radius)))
    todo = [(i, v, k, pose) for i, (v, k, pose) in planned if not writer.done(i)]
    if not todo:
        return 0
    bscene.reset(resolution, resolution, samples, denoise=samples >= 4, world_color=(1.0, 1.0, 1.0),
                 world_strength=1.0, transparent=True, device=device, threads=threads, prefilter=DENOISE_PREFILTER)
    bscene.set_camera(K, resolution, resolution, np.eye(4))
    objects = bscene.RobotObjects(model, Path(urdf_dir), {lk.name for lk in model.links})
    objects.pose(Kinematics(model).link_poses(canonical))
    unrolled = {v: pose for _, (v, k, pose) in planned if k == 0}
    for view, planned_view in groupby(todo, key=lambda t: t[1]):
        if inplane == "rotated":
            view_images = _render(unrolled[view], folder)
        templates = []
        for i, _, k, T_cam_model in planned_view:
            if inplane == "rotated":
                rgb, depth, mask = roll_template(*view_images, 2 * np.pi * k / n_inplane)
            else:
                rgb, depth, mask = _render(T_cam_model, folder)
            templates.append(Template(i, view, k, K, T_cam_model, rgb, depth, mask))
        writer.write(templates)
        if progress is not None:
            progress(len(templates))
    return len(todo)


def _render(T_cam_model: np.ndarray, folder: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sRGB uint8, depth in metres with 0 off the object, mask) seen from one camera pose. The end-effector
    is all the scene holds, so the main layer's index and depth are its full mask and depth."""
    bscene.move_camera(np.linalg.inv(T_cam_model))
    out = bscene.render(Path(folder))
    mask = out["index"] == bscene.PASS_EE
    return linear_to_srgb8(out["rgb_linear"]), np.where(mask, out["depth"], 0.0), mask
