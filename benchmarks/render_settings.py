"""Cycles settings for `mini` chosen by measurement: seconds per frame and RGB PSNR against a 256-spp
reference (no denoiser, 12 bounces) for today's settings and alternatives, on the same planned frames.

Each variant changes one thing, or a few, against today's (scenes/mini.yaml: 4 spp, OIDN denoiser with the
fast prefilter, 8 bounces, light tree, no adaptive sampling; one view layer, the end-effector's mask rasterised);
times are the render call per frame (Cycles and its EXR; the scene build excluded), the variants interleaved frame by frame so a noisy
machine slows them alike. Prints figures, asserts nothing:
`.venv/bin/python benchmarks/render_settings.py [--configs A+B,...] [--frames N] [--variants "A;B"]`.
"""

import argparse
import time

import bpy
import numpy as np

from syneepose import paths
from syneepose.blender import scene as bscene
from syneepose.colour import linear_to_srgb8
from syneepose.blender.segment import build_scene
from syneepose.preset import load_preset
from syneepose.robots.ee_models import load_ee_mesh
from syneepose.robots.robot import load_robot
from syneepose.scene.motion import MotionChecks
from syneepose.scene.plan import plan_segment

REFERENCE = {"samples": 256, "use_denoising": False, "max_bounces": 12}


LIGHT_TREE_OFF = {"use_light_tree": False}
BOUNCES_4 = {"max_bounces": 4, "diffuse_bounces": 2, "glossy_bounces": 2}
ALBEDO_ONLY = {"denoising_input_passes": "RGB_ALBEDO"}
NO_CAUSTICS = {"caustics_reflective": False, "caustics_refractive": False}
BALANCED = {"denoising_quality": "BALANCED"}
ACCURATE = {"denoising_prefilter": "ACCURATE"}
VARIANTS = {
    "today (mini.yaml: 4 spp, OIDN prefilter fast)": [],
    "before issue 36 (16 spp, OIDN prefilter accurate)": [{"samples": 16}, ACCURATE],
    "8 spp (mini until the fresh-checkout measure of issue 36)": [{"samples": 8}],
    "16 spp": [{"samples": 16}],
    "12 spp": [{"samples": 12}],
    "OIDN prefilter accurate": [ACCURATE],
    "OIDN quality BALANCED": [BALANCED],
    "OIDN on RGB + albedo (no normal)": [ALBEDO_ONLY],
    "4 bounces (diffuse/glossy 2)": [BOUNCES_4],
    "caustics off": [NO_CAUSTICS],
    "light tree off": [LIGHT_TREE_OFF],
    "light tree off, 4 bounces": [LIGHT_TREE_OFF, BOUNCES_4],
    "light tree off, 4 bounces, caustics off, RGB + albedo": [LIGHT_TREE_OFF, BOUNCES_4, NO_CAUSTICS, ALBEDO_ONLY],
}


def build(config: str, frame_count: int, seed: int):
    preset = load_preset("mini")
    robot = load_robot(config)
    mesh = load_ee_mesh(robot.ee, paths.part_urdf(robot.ee.name))
    spec = plan_segment(preset, robot, MotionChecks(robot, mesh), seed, 0, frame_count, *preset.resolution)
    return robot, spec, preset


def render_frame(robot, spec, preset, changes: list, frame: int) -> tuple[np.ndarray, float]:
    """A fresh scene with `changes` applied, one frame: (sRGB as float, seconds in Blender's render call)."""
    objects = build_scene(spec, preset.render_settings(), robot)
    for part in changes:
        for key, value in part.items():
            setattr(bpy.context.scene.cycles, key, value)
    objects.pose(robot.T_base_link(spec.q[frame]))
    start = time.perf_counter()
    out = bscene.render()
    return linear_to_srgb8(out["rgb_linear"]).astype(float), time.perf_counter() - start


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(255.0**2 / max(np.mean((a - b) ** 2), 1e-12)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", default="ur5e+robotiq_2f85,panda+panda_hand,ur10e+shadow_hand")
    parser.add_argument("--frames", type=int, default=2, help="frames per configuration, spread over a segment")
    parser.add_argument("--variants", default="",
                        help="names separated by ; to run beside today's (default: all)")
    args = parser.parse_args()
    names = [name for name in args.variants.split(";") if name]
    if set(names) - set(VARIANTS):
        parser.error(f"unknown variant(s) {sorted(set(names) - set(VARIANTS))}; choose from {list(VARIANTS)}")
    today = next(iter(VARIANTS))
    variants = {name: VARIANTS[name] for name in [today, *names]} if names else VARIANTS
    n = load_preset("mini").frames
    frames = sorted({round(k * (n - 1) / max(args.frames - 1, 1)) for k in range(args.frames)})
    results = {name: ([], []) for name in variants}
    for seed, config in enumerate(args.configs.split(",")):
        robot, spec, preset = build(config, n, seed)
        for frame in frames:
            reference, _ = render_frame(robot, spec, preset, [REFERENCE], frame)
            for name, change in variants.items():
                image, seconds = render_frame(robot, spec, preset, change, frame)
                results[name][0].append(psnr(image, reference))
                results[name][1].append(seconds)
    base = np.mean(results[today][1])
    print(f"mini, 320x240, {len(frames)} frames x {len(args.configs.split(','))} configurations; "
          "PSNR against 256 spp / no denoiser / 12 bounces")
    for name, (psnrs, seconds) in results.items():
        print(f"  {name:40s} {np.mean(seconds):5.2f} s/frame (x{np.mean(seconds) / base:.2f})  "
              f"PSNR {np.mean(psnrs):5.2f} dB (min {np.min(psnrs):5.2f})")


if __name__ == "__main__":
    main()
