"""`python -m eval.targeting`: the paper's high-precision targeting experiment, in simulation.

Each configuration is rendered twice with the same robot motion, camera and lights: with a ChArUco board
bolted to the end-effector (`render --marker`) and without (`render`). For every number of views N
(3, 5, 10, 15, 20) and each of `--draws` random draws of N of the segment's frames, the marker method
runs online over those frames of the marker segment (calibrating from their board poses with
`cv2.calibrateHandEye`, Tsai by default, as the paper's baseline) and FEEPE over the same frames of the
marker-free twin, both in frame order; both camera-to-base poses are scored at 5 fixed workspace points
(mean distance, mm) and in rotation. The two are the registered `handeye` and `feepe` methods, built and
checked as `eval.run` builds them from the same options (`--hand-eye`, `--refine`, `--silhouette`, ...),
and see frames as `eval.run` hands them (`--mask-noise`, `--depth-dir` for FEEPE). Render with `--preset
targeting-stations` for the fair marker peer: stations where the board is seen in every view
(syneepose/scene/stations.py); the marker rows then carry the preset.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eval.mask_noise import MaskNoise, mask_noise
from eval.methods import build_method
from eval.methods.base import Estimate
from eval.metrics import WORKSPACE_POINTS, calibration_error
from eval.run import NO_POSE, observation
from eval.tables import method_label
from feepe.backbones import DEFAULT as DEFAULT_BACKBONE
from kernel.bop import DEPTH_DIR
from kernel.cli import output_dir, run_command
from kernel.dataset import TEMPLATES, Dataset, Scene
from kernel.errors import UserError
from kernel.files import write_atomic

VIEWS = (3, 5, 10, 15, 20)
FIELDS = ("method", "scene_id", "config", "views", "draw", "points_mm", "rot_deg", "detected")


@dataclass
class Trial:
    method: str
    scene_id: int
    config: str
    views: int
    draw: int
    points_mm: float  # mean over the workspace points; inf when the method gave no calibration
    rot_deg: float
    detected: int  # frames the method could use (board found / FEEPE gave a pose)


def _pairs(marker_root: Path, plain_root: Path) -> list[tuple[Scene, Scene]]:
    """The scenes of the marker data set with their twins (same id) in the plain one."""
    marker, plain = Dataset(marker_root), Dataset(plain_root)
    common = sorted(set(marker.scene_dirs()) & set(plain.scene_dirs()))
    if not common:
        raise UserError(f"no scene is in both {marker.split_dir} and {plain.split_dir}; render the "
                        "same --preset/--seed/--robots twice, once with --marker")
    pairs = []
    for scene_id in common:
        m, p = marker.scene(scene_id), plain.scene(scene_id)
        if m.meta.marker is None:
            raise UserError(f"{m.path}: no marker board; render it with --marker")
        if not np.allclose(m.meta.T_cam_base, p.meta.T_cam_base, atol=1e-9) or m.im_ids != p.im_ids:
            raise UserError(f"scene {scene_id}: the marker and plain renders differ (camera or frames); render both "
                            "with the same preset, seed, robots and frame count")
        pairs.append((m, p))
    return pairs


def _error(T_est: np.ndarray | None, T_gt: np.ndarray) -> tuple[float, float]:
    if T_est is None:
        return np.inf, np.inf
    err = calibration_error(T_est, T_gt, WORKSPACE_POINTS)
    return float(err.points_mm.mean()), float(err.rot_deg[0])


def _depth_label(root: Path, depth_dir: str) -> str:
    kind = Dataset(root).info.get("depth_dirs", {}).get(depth_dir, "exact")
    return f"{kind} depth" if kind != "exact" else ""


def feepe_label(options: dict, plain_root: Path, depth_dir: str, noise: MaskNoise | None) -> str:
    """FEEPE's row name from its options and what it saw, as eval.tables names runs."""
    name = method_label("FEEPE", options)
    seen = [v for v in (_depth_label(plain_root, depth_dir), "perturbed masks" if noise else "") if v]
    return name + (f" ({', '.join(seen)})" if seen else "")


def _check(views, draws: int, seed: int, frames: int) -> None:
    """Every option before any frame is read: a mistake is one line and writes nothing."""
    if not views or any(not 1 <= n <= frames for n in views):
        raise UserError(f"--views {','.join(map(str, views))}: each number must lie in 1..{frames}, the frames of "
                        "the shortest segment (hand-eye calibrates from 3 views on)")
    if len(set(views)) != len(views):
        raise UserError(f"--views {','.join(map(str, views))}: name each number of views once")
    if not 1 <= draws <= 1000:
        raise UserError(f"--draws {draws}: must lie in 1..1000")
    if seed < 0:
        raise UserError(f"--seed {seed}: must be >= 0")


def _online(method, scene: Scene, observations: list) -> list[Estimate]:
    """The method over the chosen frames in frame order, from a fresh start, the calibration hidden."""
    method.start_scene(dataclasses.replace(scene.meta, T_cam_base=NO_POSE.copy()), scene.path)
    return [method.estimate(obs) for obs in observations]


def _observations(scene: Scene, depth_dir: str, noise: MaskNoise | None) -> dict:
    return {i: observation(scene, i, depth_dir, noise)[0] for i in scene.im_ids}


def run(marker_root: Path, plain_root: Path, views=VIEWS, draws: int = 3, seed: int = 0, hand_eye: str = "tsai",
        feepe: dict | None = None, depth_dir: str = DEPTH_DIR, noise: MaskNoise | None = None) -> list[Trial]:
    """`feepe`: the FEEPE method's options as `eval.run --method feepe` takes them (variant, icp, refine, ...)."""
    pairs = _pairs(Path(marker_root), Path(plain_root))
    _check(views, draws, seed, min(len(m.im_ids) for m, _ in pairs))
    marker = build_method("handeye", {"hand_eye": hand_eye})
    estimator = build_method("feepe", feepe or {})
    feepe_name = feepe_label(estimator.options(), Path(plain_root), depth_dir, noise)
    preset = Path(Dataset(Path(marker_root)).info.get("preset") or "targeting").stem
    marker_name = "marker hand-eye" + (f" ({preset})" if preset != "targeting" else "")  # the old rows' name
    trials, rng = [], np.random.default_rng(seed)
    bar = tqdm(total=len(pairs) * len(views) * draws, unit="trial", desc="targeting")
    for marker_scene, plain_scene in pairs:
        config, scene_id, ids = marker_scene.config, marker_scene.scene_id, marker_scene.im_ids
        T_cam_base = marker_scene.meta.T_cam_base
        boards, frames = _observations(marker_scene, DEPTH_DIR, None), _observations(plain_scene, depth_dir, noise)
        for n in views:
            for draw in range(draws):
                chosen = sorted(rng.choice(ids, n, replace=False).tolist())
                by_board = _online(marker, marker_scene, [boards[i] for i in chosen])
                trials.append(Trial(marker_name, scene_id, config, n, draw,
                                    *_error(by_board[-1].T_cam_base, T_cam_base), by_board[-1].extra["views"]))
                by_feepe = _online(estimator, plain_scene, [frames[i] for i in chosen])
                trials.append(Trial(feepe_name, scene_id, config, n, draw,
                                    *_error(by_feepe[-1].T_cam_base, T_cam_base),
                                    sum(r.T_cam_ee is not None for r in by_feepe)))
                bar.update()
    bar.close()
    return trials


def summarise(trials: list[Trial]) -> dict:
    """Per method and number of views: median and mean over scenes x draws (failures count as inf)."""
    out: dict = {}
    for t in trials:
        out.setdefault(t.method, {}).setdefault(str(t.views), []).append((t.points_mm, t.rot_deg))
    return {m: {v: {"points_mm_median": float(np.median([e[0] for e in errs])),
                    "points_mm_mean": float(np.mean([e[0] for e in errs])),
                    "rot_deg_median": float(np.median([e[1] for e in errs])),
                    "failures": int(sum(not np.isfinite(e[0]) for e in errs)), "trials": len(errs)}
                for v, errs in per.items()} for m, per in out.items()}


def write(out: Path, trials: list[Trial], options: dict) -> dict:
    out = output_dir(out)
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(FIELDS)
    writer.writerows([[getattr(t, f) for f in FIELDS] for t in trials])
    write_atomic(out / "targeting.csv", text.getvalue().encode())
    summary = {"options": options, "workspace_points_m": WORKSPACE_POINTS.tolist(), "by_method": summarise(trials)}
    write_atomic(out / "targeting.json", json.dumps(summary, indent=2).encode())
    return summary


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m eval.targeting", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--marker", required=True, type=Path, help="data set rendered with --marker")
    parser.add_argument("--plain", required=True, type=Path, help="the same scenes rendered without the board")
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--views", default=",".join(map(str, VIEWS)), help="numbers of views, e.g. 3,5,10,15,20")
    parser.add_argument("--draws", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--hand-eye", default="tsai", help="tsai, park, horaud, andreff or daniilidis")
    parser.add_argument("--variant", default="D", choices=["A", "B", "C", "D"])
    parser.add_argument("--icp", action="store_true", help="FEEPE with depth alignment (our extension)")
    parser.add_argument("--refine", default="none", help="FEEPE's refinement: none, silhouette or silhouette+depth")
    parser.add_argument("--silhouette", default="ee", help="the refinement's outline: ee or robot")
    parser.add_argument("--backbone", default=DEFAULT_BACKBONE)
    parser.add_argument("--templates-dir", type=Path, help=f"FEEPE templates (default: PLAIN/{TEMPLATES})")
    parser.add_argument("--depth-dir", default=DEPTH_DIR, help="FEEPE's depth folder in PLAIN (e.g. depth_gt)")
    parser.add_argument("--mask-noise", default="none", help="none or sam: FEEPE's masks perturbed as eval.run's")
    args = parser.parse_args(argv)

    def action() -> str:
        try:
            views = tuple(int(v) for v in args.views.split(","))
        except ValueError:
            raise UserError(f"--views {args.views!r} must be comma-separated integers") from None
        feepe = {"variant": args.variant, "icp": args.icp, "refine": args.refine, "silhouette": args.silhouette,
                 "backbone": args.backbone}
        if args.templates_dir is not None:
            feepe["templates_dir"] = str(args.templates_dir)
        trials = run(args.marker, args.plain, views, args.draws, args.seed, args.hand_eye, feepe, args.depth_dir,
                     mask_noise(args.mask_noise))
        options = {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}
        summary = write(args.out, trials, options)
        lines = [f"{m} {v} views: {s['points_mm_median']:.2f} mm, {s['rot_deg_median']:.3f} deg"
                 for m, per in summary["by_method"].items() for v, s in per.items()]
        return "targeting (median over scenes x draws):\n" + "\n".join(lines) + f"\n{args.out}/targeting.json"

    return run_command(action)


if __name__ == "__main__":
    sys.exit(main())
