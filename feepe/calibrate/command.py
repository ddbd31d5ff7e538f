"""`python -m feepe calibrate RECORDING ...` (console script `feepe calibrate`): a recording in, the
camera-to-base transform out in the forms a robot stack loads, with per-frame residuals, an uncertainty
and a verdict. A recording the command cannot use writes nothing; a run that finds the robot in no frame
writes only frames.csv and calibration.json (no transform). docs/calibrate.md is the user's guide."""

from __future__ import annotations

import argparse
import csv
import io
import logging
import os
import shutil
from pathlib import Path

import numpy as np

from feepe.calibrate.bag import Topics, is_bag, read_bag
from feepe.calibrate.folder import FolderWriter, read_folder
from feepe.calibrate.page import Overlays, write_page
from feepe.calibrate.outputs import Frames, as_handeye_yaml, as_json, as_static_transform_publisher, as_urdf_joint
from feepe.calibrate.recording import Recording, thinned
from feepe.calibrate.robot import UrdfRobot
from feepe.calibrate.solve import MASKS, Solve, SolveSettings, check, solve
from feepe.calibrate.uncertainty import estimate
from feepe.calibrate.verdict import judge
from kernel.cli import output_dir, run_command
from kernel.errors import UserError
from kernel.files import read_json, write_atomic, write_json
from kernel.transforms import inv_T

FRAME_COLUMNS = ("frame", "stamp_s", "estimated", "key_frame", "outline_px", "outline_mm", "depth_mm", "depth_agree",
                 "ms")


SAVED = ("urdf", "ee_link", "templates", "model", "base_link", "mesh_dir", "camera_frame", "masks")  # for --resume
REQUIRED = ("urdf", "ee_link", "templates", "model")
DEFAULTS = {"camera_frame": "camera_color_optical_frame", "masks": "none"}
SAMPLES = "samples"  # the frames as read and paired, a recording folder in the output folder


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="feepe calibrate", description=__doc__.split("\n\n")[0])
    p.add_argument("recording", type=Path, nargs="?", help="a recording folder (docs/calibrate.md), a ROS 1 .bag, "
                   "a ROS 2 bag folder or an .mcap file")
    p.add_argument("--urdf", type=Path, help="the robot's URDF (its meshes readable by trimesh)")
    p.add_argument("--ee-link", help="the URDF link whose frame is the end-effector model's frame")
    p.add_argument("--templates", type=Path, help="the end-effector's template set (python -m syneepose templates)")
    p.add_argument("--model", type=Path, help="the end-effector's model, .ply in mm, in --ee-link's frame")
    p.add_argument("--base-link", help="the frame the calibration is given in (default: the URDF's root link)")
    p.add_argument("--mesh-dir", type=Path, help="where package:// mesh paths start (default: beside the URDF)")
    p.add_argument("--camera-frame", help="the camera's optical frame as your stack names it (default: "
                   "realsense2_camera's camera_color_optical_frame)")
    p.add_argument("--masks", choices=MASKS, help="none (default): the estimator finds and segments the robot "
                   "itself; given: the recording's end-effector masks enter as a prior")
    p.add_argument("--out", type=Path, default=Path("calibration"), help="output folder (default: ./calibration)")
    p.add_argument("--resume", action="store_true", help=f"solve again from --out's {SAMPLES}/ (the frames as read) "
                   "with the options saved there; options given now replace them")
    p.add_argument("--topics", help="bags: key=topic pairs for color, depth (none: RGB only), camera_info, joint_states")
    p.add_argument("--sync-tolerance", type=float, default=0.02,
                   help="bags: a colour frame's depth image at most this far in time, s (default 0.02)")
    p.add_argument("--joint-gap", type=float, default=0.1,
                   help="bags: joint states around a colour frame at most this far apart, s (default 0.1)")
    p.add_argument("--every", type=int, default=1, help="take every N-th frame (default 1: all)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def settled(args: argparse.Namespace) -> argparse.Namespace:
    """The arguments with --resume's saved ones filled in, the defaults set, and the required ones checked."""
    if args.resume:
        if args.recording is not None:
            raise UserError(f"--resume solves again from {args.out / SAMPLES}; give no recording with it")
        saved_path = args.out / "calibration.json"
        if not (args.out / SAMPLES).is_dir() or not saved_path.is_file():
            raise UserError(f"--resume: {args.out} holds no saved run ({SAMPLES}/ and calibration.json); "
                            "run once without --resume, or point --out at that run's folder")
        saved = read_json(saved_path, "run without --resume to write it again").get("arguments", {})
        for key in SAVED:
            if getattr(args, key) is None and saved.get(key) is not None:
                setattr(args, key, Path(saved[key]) if key in ("urdf", "templates", "model", "mesh_dir") else saved[key])
        args.recording = args.out / SAMPLES
    for key, value in DEFAULTS.items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    missing = [f"--{key.replace('_', '-')}" for key in REQUIRED if getattr(args, key) is None]
    if args.recording is None:
        missing.insert(0, "RECORDING")
    if missing:
        raise UserError(f"missing {', '.join(missing)}: python -m feepe calibrate RECORDING --urdf URDF --ee-link LINK "
                        "--templates SET --model EE.ply (docs/calibrate.md)")
    return args


def read_recording(args) -> Recording:
    for flag, value in (("--sync-tolerance", args.sync_tolerance), ("--joint-gap", args.joint_gap)):
        if not value > 0:
            raise UserError(f"{flag} must be a positive number of seconds, got {value}")
    if args.every < 1:
        raise UserError(f"--every must be 1 or more, got {args.every}")
    if not args.recording.exists():
        raise UserError(f"{args.recording}: no such folder or bag")
    if is_bag(args.recording):
        found = read_bag(args.recording, Topics.parse(args.topics), args.sync_tolerance, args.joint_gap)
    else:
        found = read_folder(args.recording)
    return thinned(found, args.every)


def calibrate(args) -> str:
    args = settled(args)
    robot = UrdfRobot(args.urdf, args.ee_link, args.base_link, args.mesh_dir)
    recording = read_recording(args)
    settings = SolveSettings(args.templates, args.model, args.masks)
    partial = None if args.resume else args.out.parent / f".{args.out.name}.{SAMPLES}.partial{os.getpid()}"
    try:  # the samples are written beside --out while read, and moved in once the run has succeeded
        writer = None if partial is None else FolderWriter(partial)
        result = solve(recording, robot, settings, progress=not args.quiet, keep=writer and writer.add)
        if writer is not None:
            writer.close()
        overlays = Overlays(len(result.frames))
        check(result, recording, robot, overlays)
        output_dir(args.out)
        report, calibrated = write_outputs(args, robot, recording, result, overlays)
    except BaseException:
        if partial is not None:
            shutil.rmtree(partial, ignore_errors=True)
        raise
    if partial is not None:
        shutil.rmtree(args.out / SAMPLES, ignore_errors=True)
        os.replace(partial, args.out / SAMPLES)
    if not calibrated:
        raise UserError(report)
    return report


def summary(result: Solve) -> dict:
    """The calibration, its uncertainty at the workspace and the verdict, as calibration.json carries them."""
    estimated = [f for f in result.frames if f.T_cam_base is not None]
    T_base_ee = np.stack([f.T_base_ee for f in result.frames])

    def median(key: str) -> float:
        values = [getattr(f, key) for f in estimated if np.isfinite(getattr(f, key))]
        return float(np.median(values)) if values else float("nan")

    uncertainty = estimate([f.T_cam_base for f in estimated], result.T_cam_base, T_base_ee[:, :3, 3],
                           median("depth_mm"), median("pixel_mm"))
    verdict = judge(len(result.frames), len(estimated), median("outline_px"), median("depth_agree"), uncertainty,
                    T_base_ee)
    bound = {"two_sigma_mm": 2 * uncertainty.sigma_mm, "scatter_two_sigma_deg": 2 * uncertainty.sigma_deg,
             "scatter_sigma_mm": uncertainty.scatter_mm, "shared_sigma_mm": uncertainty.shared_mm,
             "at": "the end-effector's recorded positions (mean displacement)", "over_frames": uncertainty.frames,
             "not_stated_because": uncertainty.missing}
    return _json_safe({
        "frames": len(result.frames), "estimated_frames": len(estimated),
        "key_frames": [f.name for f in result.frames if f.key_frame],
        **{f"median_{key}": median(key) for key in ("outline_px", "outline_mm", "depth_mm", "pixel_mm", "depth_agree")},
        "uncertainty": bound, "verdict": verdict.word, "verdict_line": verdict.line(),
        "ms_per_frame": float(np.mean([f.ms for f in result.frames]))})


def _json_safe(value):
    """NaN (not measured) as null: strict JSON readers refuse NaN."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    return None if isinstance(value, float) and not np.isfinite(value) else value


def write_outputs(args, robot: UrdfRobot, recording: Recording, result: Solve,
                  overlays: Overlays) -> tuple[str, bool]:
    """The files of a run and its report; False when no frame had an estimate (only frames.csv and
    calibration.json, without a transform, are written then)."""
    found = summary(result)
    found["arguments"] = {key: _saved(getattr(args, key)) for key in SAVED}
    out = args.out
    table = _frames_csv(result)
    write_atomic(out / "frames.csv", table.encode())
    if result.T_cam_base is None:
        write_json(out / "calibration.json", {"source": recording.source, "sync": recording.sync, **found})
        return f"{found['verdict_line']} (per-frame results in {out / 'frames.csv'})", False
    T = inv_T(result.T_cam_base)
    frames = Frames(robot.base_link, args.camera_frame, robot.ee_link)
    write_json(out / "calibration.json", as_json(T, frames, {"source": recording.source, "sync": recording.sync,
                                                            **found, "estimator": result.options}))
    write_atomic(out / "easy_handeye2.yaml", as_handeye_yaml(T, frames, args.out.resolve().name).encode())
    write_atomic(out / "static_transform_publisher.sh", as_static_transform_publisher(T, frames).encode())
    write_atomic(out / "camera_joint.urdf.xml", as_urdf_joint(T, frames).encode())
    t = T[:3, 3]
    bound = found["uncertainty"]
    told = (f" (no uncertainty stated: {bound['not_stated_because']})" if bound["two_sigma_mm"] is None
            else f" +- {bound['two_sigma_mm']:.2f} mm (2 sigma, at the workspace)")
    lines = [f"T_base_camera ({robot.base_link} -> {args.camera_frame}): t = [{t[0]:.4f}, {t[1]:.4f}, {t[2]:.4f}] m{told}",
             f"{found['estimated_frames']}/{found['frames']} frames estimated, outline "
             f"{_told(found['median_outline_px'], 'px')}, depth {_told(found['median_depth_mm'], 'mm')} (medians)",
             f"verdict: {found['verdict_line']}"]
    write_page(out, found, table, overlays, lines)
    return "\n".join(lines + [f"written to {out}/ (report.html to judge it by eye)"]), True


def _saved(value):
    """An argument as --resume reads it back: paths absolute (it may run from another folder)."""
    return None if value is None else str(value.resolve()) if isinstance(value, Path) else value


def _told(value: float | None, unit: str) -> str:
    return "not measured" if value is None else f"{value:.2f} {unit}"


def _frames_csv(result: Solve) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(FRAME_COLUMNS)
    for f in result.frames:
        w.writerow([f.name, f"{f.stamp:.9f}", int(f.T_cam_base is not None), int(f.key_frame), f"{f.outline_px:.3f}",
                    f"{f.outline_mm:.3f}", f"{f.depth_mm:.3f}", f"{f.depth_agree:.4f}", f"{f.ms:.1f}"])
    return buf.getvalue()


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    logging.getLogger("trimesh").setLevel(logging.ERROR)  # its sampler's shortfall warnings are not the user's
    return run_command(lambda: calibrate(args))
