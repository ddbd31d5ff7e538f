"""Render benchmark: seconds per frame at 640x480 / 16 spp on a fixed scene, our overhead over a bare
Cycles render of the same scene (the two alternated), and resident memory over a 300-frame segment.

Prints figures, asserts nothing: `make bench` or `.venv/bin/python benchmarks/render.py [--quick]`.
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from syneepose import paths
from syneepose.blender.segment import build_scene, render_segment
from syneepose.preset import load_preset
from syneepose.robots.ee_models import load_ee_mesh
from syneepose.robots.robot import load_robot
from syneepose.scene.motion import MotionChecks
from syneepose.scene.plan import plan_segment
from syneepose.scene.spec import RenderSettings

CONFIG = "ur5e+robotiq_2f85"


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def spec_for(frames: int, width: int, height: int, samples: int):
    robot = load_robot(CONFIG)
    mesh = load_ee_mesh(robot.ee, paths.part_urdf(robot.ee.name))
    spec = plan_segment(load_preset("mini"), robot, MotionChecks(robot, mesh), 0, 0, frames, width, height)
    return robot, mesh, spec, RenderSettings(width, height, samples, denoise=False, max_bounces=12)


def bare_cycles(robot, spec, render, frames: int) -> float:
    """The same scene and poses, timing only bpy's render call (no FK, EXR read, PNG or JSON)."""
    import bpy

    objects = build_scene(spec, render, robot)
    poses = [robot.T_base_link(q) for q in spec.q]
    with tempfile.TemporaryDirectory() as tmp:
        bpy.context.scene.render.filepath = str(Path(tmp) / "bare.exr")
        t0 = time.perf_counter()
        for i in range(frames):
            objects.pose(poses[i])
            bpy.ops.render.render(write_still=True)
        return (time.perf_counter() - t0) / frames


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="3 frames and a 60-frame memory run")
    args = parser.parse_args()
    frames, pairs = (3, 1) if args.quick else (6, 3)
    robot, mesh, spec, render = spec_for(frames, 640, 480, 16)
    ours, bare = [], []
    with tempfile.TemporaryDirectory() as tmp:
        render_segment(spec, render, robot, mesh, Path(tmp) / "warm", None)
        for k in range(pairs):  # alternated, so a machine that slows down slows both alike
            t0 = time.perf_counter()
            render_segment(spec, render, robot, mesh, Path(tmp) / f"timed{k}", None)
            ours.append((time.perf_counter() - t0) / frames)
            bare.append(bare_cycles(robot, spec, render, frames))
    ratio = np.median(np.array(ours) / np.array(bare))
    print(f"640x480, 16 spp, {frames} frames, {CONFIG}, {pairs} alternated pairs: ours {np.median(ours):.2f} s/frame "
          f"(incl. scene build), bare Cycles {np.median(bare):.2f} s/frame, overhead {100 * (ratio - 1):+.1f} % "
          f"(median of the pairs' ratios; each: {', '.join(f'{o / b:.3f}' for o, b in zip(ours, bare))})")

    n = 60 if args.quick else 300
    robot, mesh, spec, render = spec_for(n, 160, 120, 1)
    marks = {}
    with tempfile.TemporaryDirectory() as tmp:
        done = [0]

        def progress(_):
            done[0] += 1
            if done[0] in (1, n // 3, 2 * n // 3, n):
                marks[done[0]] = rss_mb()

        render_segment(spec, render, robot, mesh, Path(tmp) / "memory", progress)
    print(f"resident memory over a {n}-frame segment (160x120, 1 spp): "
          + ", ".join(f"frame {k}: {v:.0f} MB" for k, v in sorted(marks.items())))


if __name__ == "__main__":
    main()
