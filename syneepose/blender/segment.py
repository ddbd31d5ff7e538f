"""Render one planned segment into one BOP scene (runs inside a worker process)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh

from feepe import raster
from kernel.bop import MAX_DEPTH, Frame, SceneMeta, SceneWriter
from kernel.transforms import inv_T
from syneepose.blender import scene as bscene
from syneepose.colour import linear_to_srgb8
from syneepose.blender.stereo import IrRig
from syneepose.ir_shading import Lighting
from syneepose.robots.catalog import load_catalog
from syneepose.robots.robot import Robot
from syneepose.scene.spec import RenderSettings, SegmentSpec
from syneepose.stereo import load_profile, stereo_depth, to_rgb_camera


def _with_sensor_depth(frame: Frame, rig: IrRig, spec: SegmentSpec, render: RenderSettings, workdir: Path) -> Frame:
    """The frame with the stereo sensor's depth in `depth` and the exact depth kept as `depth_gt`."""
    left, right = rig.render_pair(spec.T_base_cam, workdir, frame.im_id)
    depth_ir = stereo_depth(left, right, rig.profile, rig.K_ir)
    sensed = to_rgb_camera(depth_ir, rig.K_ir, rig.profile.T_rgb_irleft, spec.K, render.width, render.height)
    sensed = np.where(sensed < MAX_DEPTH, sensed, 0.0)  # beyond the PNG's range: 0, as a sensor reports it
    keep_ir = render.depth == "both"
    return replace(frame, depth=sensed, depth_gt=frame.depth, ir_left=left if keep_ir else None,
                   ir_right=right if keep_ir else None)


def build_scene(spec: SegmentSpec, render: RenderSettings, robot: Robot) -> bscene.RobotObjects:
    """A fresh Cycles scene of the segment (camera, lights, backdrop, distractors, robot), the robot not yet
    posed; what the renderer and the render benchmarks start from."""
    bscene.reset(render.width, render.height, render.samples, render.denoise, render.max_bounces, spec.world_color,
                 spec.world_strength, device=render.device, threads=render.threads,
                 prefilter=render.denoise_prefilter)
    bscene.set_camera(spec.K, render.width, render.height, spec.T_base_cam)
    bscene.add_lights(spec.lights)
    bscene.add_planes(spec.planes)
    bscene.add_distractors(spec.distractors)
    return bscene.RobotObjects(robot.model, robot.urdf.parent, set(robot.ee_links))


def ee_mask(vertices: np.ndarray, faces: np.ndarray, T_cam_ee: np.ndarray, K: np.ndarray,
            mask_visib: np.ndarray) -> np.ndarray:
    """BOP's `mask`, the end-effector's occlusion-free silhouette: rasterised, no longer a Cycles layer (issue 36).
    Where the end-effector is seen it is in its silhouette: the raster and Cycles can part on a pixel centre
    that lies on an edge (16 of the 428,227 silhouette pixels of the 288 mini frames), and BOP's mask holds
    mask_visib."""
    return raster.silhouette(vertices, faces, T_cam_ee, K, mask_visib.shape) | mask_visib


def render_segment(spec: SegmentSpec, render: RenderSettings, robot: Robot, ee_mesh: trimesh.Trimesh, scene_dir: Path,
                   progress=None, settings: dict | None = None) -> int:
    """Render the frames not yet on disk; returns how many were rendered. `ee_mesh`: the end-effector's rigid
    model (ee_models.load_ee_mesh), whose silhouette is each frame's `mask`. `settings`: what produced them
    (jobs.job_settings), recorded in scene_robot.json; frames of other settings are refused."""
    sensor = load_profile(render.sensor, render.sensor_render) if render.depth != "exact" else None
    writer = SceneWriter(Path(scene_dir), SceneMeta(
        obj_id=robot.ee.obj_id, arm=robot.arm.name, end_effector=robot.ee.name,
        joint_names=list(robot.arm.joints), T_cam_base=inv_T(spec.T_base_cam),
        marker=spec.marker.to_json() if spec.marker is not None else None,
        depth_sensor={"mode": render.depth, "profile": sensor.source} if sensor is not None else None,
        links=[*robot.arm_links, robot.ee_root], settings=settings,
        dropped_distractors=spec.dropped_distractors),
        obj_ids=[ee.obj_id for ee in load_catalog().end_effectors.values()])
    todo = [i for i in range(spec.n_frames) if not writer.done(i)]
    if not todo:
        return 0
    objects = build_scene(spec, render, robot)
    ee_vertices, ee_faces = np.asarray(ee_mesh.vertices, float), np.asarray(ee_mesh.faces, np.int64)
    board = bscene.add_board(spec.marker) if spec.marker is not None else None
    movers = bscene.add_occluders(spec.occluders)
    rig = None
    if sensor is not None:
        lighting = Lighting.of(spec.lights, spec.world_color, spec.world_strength, sensor.ambient)
        rig = IrRig(sensor, render.width, render.height, seed=spec.stream, lighting=lighting)
    T_cam_base = inv_T(spec.T_base_cam)
    for i in todo:
        q = spec.q[i]
        T_base_link = robot.T_base_link(q)
        objects.pose(T_base_link)
        if board is not None:
            board.matrix_world = (T_base_link[robot.ee_root] @ spec.marker.T_ee_board).T.tolist()
        for ob, occluder in zip(movers, spec.occluders):
            ob.matrix_world = occluder.T_base_obj[i].T.tolist()
        out = bscene.render(Path(scene_dir))
        depth = np.where(out["depth"] < MAX_DEPTH, out["depth"], 0.0)  # Cycles writes 1e10 where a ray hits nothing
        mask_visib = out["index"] == bscene.PASS_EE
        T_cam_ee = T_cam_base @ T_base_link[robot.ee_root]
        mask = ee_mask(ee_vertices, ee_faces, T_cam_ee, spec.K, mask_visib)
        frame = Frame(
            im_id=i, rgb=linear_to_srgb8(out["rgb_linear"]), depth=depth, mask=mask, mask_visib=mask_visib,
            K=spec.K, T_cam_ee=T_cam_ee, joint_positions=q,
            T_base_ee=T_base_link[robot.ee_root], link_ids=objects.link_ids(out["index"]))
        if rig is not None:
            frame = _with_sensor_depth(frame, rig, spec, render, Path(scene_dir))
        writer.write(frame)
        if progress is not None:
            progress(1)
    return len(todo)
