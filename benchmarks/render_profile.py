"""Where a `mini` frame's time goes: the segment loop of syneepose/blender/segment.py timed step by step
(forward kinematics and object poses, Blender's render call, EXR read, the end-effector's silhouette raster,
BOP write), and the render call split
by rendering the same frames again without the denoiser and at one sample (what is left is scene sync, BVH
build and the EXR write). Prints figures, asserts nothing:
`.venv/bin/python benchmarks/render_profile.py [--config ARM+EE] [--frames N]`.
"""

import argparse
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

from kernel.bop import MAX_DEPTH, Frame, SceneMeta, SceneWriter
from kernel.transforms import inv_T
from syneepose import paths
from syneepose.blender import scene as bscene
from syneepose.blender.exr import read_passes
from syneepose.colour import linear_to_srgb8
from syneepose.blender.segment import build_scene, ee_mask
from syneepose.preset import load_preset
from syneepose.robots.ee_models import load_ee_mesh
from syneepose.robots.robot import load_robot
from syneepose.scene.motion import MotionChecks
from syneepose.scene.plan import plan_segment


def render_call(path: Path) -> float:
    bpy.context.scene.render.filepath = str(path)
    start = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="ur5e+robotiq_2f85")
    parser.add_argument("--frames", type=int, default=4)
    args = parser.parse_args()
    preset = load_preset("mini")
    robot = load_robot(args.config)
    mesh = load_ee_mesh(robot.ee, paths.part_urdf(robot.ee.name))
    start = time.perf_counter()
    spec = plan_segment(preset, robot, MotionChecks(robot, mesh), 0, 0, preset.frames, *preset.resolution)
    plan_s = time.perf_counter() - start
    start = time.perf_counter()
    objects = build_scene(spec, preset.render_settings(), robot)
    build_s = time.perf_counter() - start
    frames = np.linspace(0, preset.frames - 1, args.frames).round().astype(int)
    steps = {"FK and object poses": [], "render call": [], "EXR read": [], "silhouette raster": [], "BOP write": []}
    with tempfile.TemporaryDirectory() as tmp:
        writer = SceneWriter(Path(tmp) / "scene", SceneMeta(obj_id=robot.ee.obj_id, arm=robot.arm.name,
                             end_effector=robot.ee.name, joint_names=list(robot.arm.joints),
                             T_cam_base=inv_T(spec.T_base_cam)), obj_ids=[robot.ee.obj_id])
        exr = Path(tmp) / "frame.exr"
        for i in frames:
            t0 = time.perf_counter()
            T_base_link = robot.T_base_link(spec.q[i])
            objects.pose(T_base_link)
            t1 = time.perf_counter()
            steps["render call"].append(render_call(exr))
            t2 = time.perf_counter()
            passes = read_passes(exr)
            t3 = time.perf_counter()
            visib = np.rint(passes[f"{bscene.MAIN}.Object Index"]) == bscene.PASS_EE
            T_cam_ee = inv_T(spec.T_base_cam) @ T_base_link[robot.ee_root]
            ee = ee_mask(mesh.vertices, mesh.faces, T_cam_ee, spec.K, visib)
            t4 = time.perf_counter()
            depth = passes[f"{bscene.MAIN}.Depth"]
            writer.write(Frame(im_id=int(i), rgb=linear_to_srgb8(passes[f"{bscene.MAIN}.Combined"][..., :3]),
                               depth=np.where(depth < MAX_DEPTH, depth, 0.0), mask=ee, mask_visib=visib, K=spec.K,
                               T_cam_ee=T_cam_ee,
                               joint_positions=spec.q[i], T_base_ee=T_base_link[robot.ee_root]))
            t5 = time.perf_counter()
            steps["FK and object poses"].append(t1 - t0)
            steps["EXR read"].append(t3 - t2)
            steps["silhouette raster"].append(t4 - t3)
            steps["BOP write"].append(t5 - t4)
        scene = bpy.context.scene
        calls = {}
        for label, samples in ((f"{preset.samples} spp, no denoiser", preset.samples), ("1 spp, no denoiser", 1)):
            scene.cycles.samples, scene.cycles.use_denoising = samples, False
            calls[label] = []
            for i in frames:
                objects.pose(robot.T_base_link(spec.q[i]))
                calls[label].append(render_call(exr))
    whole = sum(np.mean(v) for v in steps.values())
    print(f"mini {args.config}, {len(frames)} frames at {preset.resolution[0]}x{preset.resolution[1]}, "
          f"{preset.samples} spp + denoiser: once per segment plan {plan_s:.2f} s, scene build {build_s:.2f} s")
    for name, values in steps.items():
        print(f"  {name:22s} {np.mean(values):6.3f} s/frame ({100 * np.mean(values) / whole:4.1f} %)")
    full, plain, one = np.mean(steps["render call"]), *(np.mean(v) for v in calls.values())
    print(f"  render call split: denoiser {full - plain:.2f} s, path tracing at {preset.samples} spp beyond the first "
          f"{plain - one:.2f} s, the rest (first sample, sync, BVH, EXR write) {one:.2f} s")


if __name__ == "__main__":
    main()
