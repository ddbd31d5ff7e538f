"""`python -m eval.calibration_tool DATASET --out DIR`: the calibration tool (`python -m feepe calibrate`,
docs/calibrate.md) run as a user runs it, on each rendered segment written as the ROS 2 bag their camera and
robot would record (eval/recordings.py), and scored against the truth: the calibration's error where the
tool states its bound (the mean displacement of the end-effector's recorded positions), whether the stated
2-sigma bound covers it, and the verdict. `--depth-dir depth_gt` puts a stereo render's exact depth in the
bags. Writes DIR/segments.csv and DIR/summary.md; the bags go to DIR/bags, the tool's folders to DIR/runs."""

from __future__ import annotations

import argparse
import csv
import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eval.metrics import calibration_error
from eval.recordings import write_bag
from kernel.bop import read_scene, scene_dirs, split_dir
from kernel.cli import output_dir, run_command
from kernel.dataset import TEMPLATES, Dataset
from kernel.errors import UserError
from kernel.files import write_atomic
from kernel.template_set import find_template_set
from kernel.transforms import inv_T

FIELDS = ("scene_id", "config", "frames", "estimated", "error_mm", "camera_mm", "camera_deg", "two_sigma_mm",
          "covered", "verdict", "ms_per_frame")


def score_segment(scene_dir: Path, templates_root: Path, out: Path, exact_depth: bool) -> dict:
    """One segment: its bag written, the tool run on it as a command, its output scored."""
    from syneepose.paths import config_urdf
    from syneepose.robots.robot import load_robot

    meta, _ = read_scene(scene_dir)
    config = f"{meta.arm}+{meta.end_effector}"
    robot_assets = load_robot(config)
    bag = out / "bags" / scene_dir.name
    if not bag.exists():
        write_bag(scene_dir, bag, exact_depth=exact_depth)
    run = out / "runs" / scene_dir.name
    cmd = [sys.executable, "-m", "feepe", "calibrate", str(bag), "--urdf", str(config_urdf(config)),
           "--ee-link", robot_assets.ee_root, "--base-link", robot_assets.arm.base_link,
           "--templates", str(find_template_set(templates_root, meta.end_effector, None)),
           "--model", str(Dataset.of_scene(scene_dir).model_path(meta.obj_id)), "--out", str(run), "--quiet"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if not (run / "calibration.json").is_file():
        raise UserError(f"{scene_dir}: the tool wrote nothing: {proc.stderr.strip()[-300:]}")
    found = json.loads((run / "calibration.json").read_text())
    robot = json.loads((scene_dir / "scene_robot.json").read_text())
    row = {"scene_id": int(scene_dir.name), "config": config, "frames": found["frames"],
           "estimated": found["estimated_frames"], "verdict": found["verdict"], "ms_per_frame": found["ms_per_frame"]}
    if "T_base_camera" not in found:
        return row
    points = np.array([np.array(f["T_base_ee"])[:3, 3] for f in robot["frames"].values()])
    error = calibration_error(inv_T(np.array(found["T_base_camera"])), np.array(robot["T_cam_base"]), points)
    error_mm, two_sigma = float(error.points_mm.mean()), found["uncertainty"]["two_sigma_mm"]
    return {**row, "error_mm": error_mm, "camera_mm": float(error.trans_mm[0]), "camera_deg": float(error.rot_deg[0]),
            "two_sigma_mm": two_sigma, "covered": None if two_sigma is None else bool(two_sigma >= error_mm)}


def summary(rows: list[dict], title: str) -> str:
    calibrated = [r for r in rows if "error_mm" in r]
    bounded = [r for r in calibrated if r["two_sigma_mm"] is not None]
    errors = [r["error_mm"] for r in calibrated]
    lines = [f"# {title}", "", f"segments {len(rows)}, calibrated {len(calibrated)}, with a bound {len(bounded)}"]
    if errors:
        lines.append(f"error at the workspace: median {np.median(errors):.2f} mm, max {max(errors):.2f} mm")
    if bounded:
        ratio = np.median([r["two_sigma_mm"] for r in bounded]) / np.median([r["error_mm"] for r in bounded])
        lines.append(f"2-sigma covers the error in {sum(r['covered'] for r in bounded)}/{len(bounded)}; median bound / "
                     f"median error {ratio:.2f}")
    verdicts = {}
    for r in rows:
        verdicts[r["verdict"]] = verdicts.get(r["verdict"], 0) + 1
    lines.append("verdicts: " + ", ".join(f"{k} {v}" for k, v in sorted(verdicts.items())))
    return "\n".join(lines) + "\n"


def evaluate(args) -> str:
    scenes = scene_dirs(split_dir(args.dataset))
    chosen = sorted(scenes) if args.scenes is None else [int(s) for s in args.scenes.split(",")]
    missing = [s for s in chosen if s not in scenes]
    if missing:
        raise UserError(f"--scenes: {args.dataset} has no scene {missing[0]} (it has {sorted(scenes)})")
    templates = Path(args.templates_dir) if args.templates_dir else Path(args.dataset) / TEMPLATES
    out = output_dir(args.out)
    rows = [score_segment(scenes[s], templates, out, args.depth_dir == "depth_gt")
            for s in tqdm(chosen, desc="calibration tool", unit="segment")]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, FIELDS)
    writer.writeheader()
    writer.writerows(rows)
    write_atomic(out / "segments.csv", buf.getvalue().encode())
    text = summary(rows, f"python -m feepe calibrate on {args.dataset} ({args.depth_dir})")
    write_atomic(out / "summary.md", text.encode())
    return text


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m eval.calibration_tool", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--templates-dir", help=f"template root (default: DATASET/{TEMPLATES})")
    parser.add_argument("--depth-dir", choices=("depth", "depth_gt"), default="depth",
                        help="the depth the bags carry: the data set's (depth) or a stereo render's exact depth")
    parser.add_argument("--scenes", help="comma-separated scene ids (default: all)")
    args = parser.parse_args(argv)
    return run_command(lambda: evaluate(args))


if __name__ == "__main__":
    sys.exit(main())
