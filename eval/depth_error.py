"""`python -m eval.depth_error DATASET --out FILE.png [--robot]`: how a simulated sensor's depth differs from
the exact depth on the end-effector (visible mask pixels), for data sets rendered with `--depth stereo|both`.

Prints the median and percentiles of the signed error, the share of end-effector pixels without sensor
depth, and writes a histogram of the signed error (mm) with one curve per end-effector. `--robot` also prints,
per segment, the error on the whole robot's visible pixels (`robot_mask_visib/`) by their distance to its
outline: a stereo matcher's window errs most near an object's edge, and the robot's depth is what the no-mask
refinement fits.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from eval.plots import save_figure
from kernel.bop import Frame
from kernel.cli import run_command
from kernel.dataset import Dataset, Scene
from kernel.errors import UserError

EDGE_BANDS_PX = (1.5, 3.5, 8.0)  # --robot: pixels by distance to the robot's outline, (0, 1.5], (1.5, 3.5], ...


def sensor_scenes(root: Path) -> list[Scene]:
    """The data set's scenes, each rendered with a simulated sensor's depth beside the exact depth."""
    scenes = Dataset(root).scenes()
    if not scenes:
        raise UserError(f"{root}: no scenes; give the root of a data set rendered with --depth stereo")
    for scene in scenes:
        if scene.meta.depth_sensor is None:
            raise UserError(f"{scene.path}: exact depth only; render with --depth stereo to compare a sensor's depth")
    return scenes


def _compared(f: Frame, region: np.ndarray) -> tuple[np.ndarray, int, int]:
    """On `region`'s pixels with exact depth: the signed errors (m) where the sensor has depth, how many
    pixels, and how many of them without sensor depth."""
    here = region & (f.depth_gt > 0)
    both = here & (f.depth > 0)
    return f.depth[both] - f.depth_gt[both], int(here.sum()), int((here & (f.depth == 0)).sum())


def ee_depth_errors(root: Path) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Per end-effector: signed errors (m) where both depths exist, and the share of pixels with no sensor depth."""
    errors, holes = defaultdict(list), defaultdict(list)
    for scene in sensor_scenes(root):
        for i in scene.im_ids:
            f = scene.frame(i)
            e, n, h = _compared(f, f.mask_visib)
            errors[scene.meta.end_effector].append(e)
            holes[scene.meta.end_effector].append((n, h))
    return ({ee: np.concatenate(e) for ee, e in errors.items()},
            {ee: sum(h for _, h in c) / max(1, sum(n for n, _ in c)) for ee, c in holes.items()})


def robot_depth_errors(root: Path) -> dict[tuple[int, str], list[tuple[np.ndarray, float]]]:
    """Per segment (scene id, configuration), per band of EDGE_BANDS_PX: the signed errors (m) on the robot's
    visible pixels at that distance to its outline (px, Euclidean, to the nearest pixel off the robot), and
    the share of them with no sensor depth."""
    found = {}
    for scene in sensor_scenes(root):
        errors, counts = [[] for _ in range(len(EDGE_BANDS_PX) + 1)], np.zeros((len(EDGE_BANDS_PX) + 1, 2))
        for i in scene.im_ids:
            f = scene.frame(i)
            if f.link_ids is None:
                raise UserError(f"{scene.path}: no robot_mask_visib/; --robot needs a render that writes the robot's parts")
            robot = f.link_ids > 0
            band = np.digitize(cv2.distanceTransform(robot.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE),
                               EDGE_BANDS_PX, right=True)
            for b in range(len(errors)):
                e, n, h = _compared(f, robot & (band == b))
                errors[b].append(e)
                counts[b] += n, h
        found[(scene.scene_id, scene.config)] = [(np.concatenate(e), h / max(n, 1)) for e, (n, h) in zip(errors, counts)]
    return found


def _bands_line(bands: list[tuple[np.ndarray, float]]) -> str:
    """Each band's median error, median |error| (mm) and share without depth, named by its distances."""
    edges = (0.0, *EDGE_BANDS_PX)
    names = [f"{a:g}-{b:g} px" for a, b in zip(edges, edges[1:])] + [f"over {EDGE_BANDS_PX[-1]:g} px"]
    return "; ".join(f"{name} " + (f"{np.median(e) * 1000:+.1f} mm, {np.median(np.abs(e)) * 1000:.1f} mm, " if len(e)
                                   else "no pixels with depth, ") + f"{100 * h:.0f}%"
                     for name, (e, h) in zip(names, bands))


def histogram(errors: dict[str, np.ndarray], path: Path, limit_mm: float = 60.0) -> None:
    fig = Figure(figsize=(7, 4))
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    bins = np.linspace(-limit_mm, limit_mm, 121)
    for ee, e in sorted(errors.items()):
        ax.hist(np.clip(e * 1000.0, -limit_mm, limit_mm), bins=bins, histtype="step", density=True, label=ee)
    ax.set(xlabel="sensor depth - exact depth (mm), end-effector pixels", ylabel="density",
           title="simulated active-stereo depth error")
    ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    save_figure(fig, path)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m eval.depth_error", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--out", type=Path, required=True, help="histogram PNG")
    parser.add_argument("--robot", action="store_true", help="also the robot's pixels per segment, by distance to "
                        "its outline (needs robot_mask_visib/)")
    args = parser.parse_args(argv)

    def action() -> str:
        errors, holes = ee_depth_errors(args.dataset)
        histogram(errors, args.out)
        lines = []
        for ee, e in sorted(errors.items()):
            q = np.percentile(e * 1000.0, [10, 50, 90])
            lines.append(f"{ee}: median {q[1]:+.1f} mm, |err| median {np.median(np.abs(e)) * 1000:.1f} mm, "
                         f"10-90% [{q[0]:+.1f}, {q[2]:+.1f}] mm, no depth on {100 * holes[ee]:.1f}% of its pixels")
        if args.robot:
            lines.append("robot pixels by distance to its outline: median error, |err| median, no depth")
            lines += [f"{scene_id} {config}: {_bands_line(bands)}"
                      for (scene_id, config), bands in sorted(robot_depth_errors(args.dataset).items())]
        return "\n".join(lines) + f"\n{args.out}"

    return run_command(action)


if __name__ == "__main__":
    sys.exit(main())
