"""What simulated stereo depth costs beside an exact-depth frame, per frame of one `mini` segment
(320x240 RGB, 640x480 IR): the exact frame's render call, then the sensor's part - the IR pair shaded from
G-buffers (the profile's default) or path-traced (`--sensor-render pathtraced`), the matching and the
re-projection - all interleaved frame by frame in one process, so a noisy machine slows them alike.

Prints seconds and the ratio (exact + sensor) / exact per IR rendering, asserts nothing:
`.venv/bin/python benchmarks/stereo_cost.py [--config ARM+EE] [--frames N] [--pathtraced]`.
"""

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

from syneepose import paths
from syneepose.blender import scene as bscene
from syneepose.blender.segment import build_scene
from syneepose.blender.stereo import IrRig
from syneepose.ir_shading import Lighting
from syneepose.preset import load_preset
from syneepose.robots.ee_models import load_ee_mesh
from syneepose.robots.robot import load_robot
from syneepose.scene.motion import MotionChecks
from syneepose.scene.plan import plan_segment
from syneepose.stereo import load_profile, stereo_depth, to_rgb_camera


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="ur5e+robotiq_2f85")
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--pathtraced", action="store_true", help="also time the path-traced IR pair")
    args = parser.parse_args()
    preset = load_preset("mini")
    robot = load_robot(args.config)
    mesh = load_ee_mesh(robot.ee, paths.part_urdf(robot.ee.name))
    width, height = preset.resolution
    spec = plan_segment(preset, robot, MotionChecks(robot, mesh), 0, 0, args.frames, width, height)
    objects = build_scene(spec, preset.render_settings(), robot)
    shaded = load_profile("d435", "shaded")
    lighting = Lighting.of(spec.lights, spec.world_color, spec.world_strength, shaded.ambient)
    rigs = {"shaded": IrRig(shaded, width, height, seed=spec.stream, lighting=lighting)}
    if args.pathtraced:
        rigs["pathtraced"] = IrRig(load_profile("d435", "pathtraced"), width, height, seed=spec.stream)
    times = {"exact": [], **{name: [] for name in rigs}, "matching": []}
    with tempfile.TemporaryDirectory() as work:
        for i in range(args.frames):
            objects.pose(robot.T_base_link(spec.q[i]))
            start = time.perf_counter()
            bscene.render(Path(work))
            times["exact"].append(time.perf_counter() - start)
            for name, rig in rigs.items():
                start = time.perf_counter()
                left, right = rig.render_pair(spec.T_base_cam, Path(work), i)
                times[name].append(time.perf_counter() - start)
            start = time.perf_counter()
            depth = stereo_depth(left, right, rig.profile, rig.K_ir)
            to_rgb_camera(depth, rig.K_ir, rig.profile.T_rgb_irleft, spec.K, width, height)
            times["matching"].append(time.perf_counter() - start)
    mean = {name: float(np.mean(values)) for name, values in times.items()}
    print(f"{args.config}, {args.frames} frames at {width}x{height} (IR {rigs['shaded'].ir_size[0]}x"
          f"{rigs['shaded'].ir_size[1]}), seconds per frame:")
    for name, value in mean.items():
        print(f"  {name:<11} {value:7.3f}")
    for name in rigs:
        ratio = (mean["exact"] + mean[name] + mean["matching"]) / mean["exact"]
        print(f"stereo frame ({name} IR) / exact frame: {ratio:.2f}")


if __name__ == "__main__":
    main()
