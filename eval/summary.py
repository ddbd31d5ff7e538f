"""The figures of a run, from its errors.csv rows: ADD / ADD-S AUC per end-effector, per configuration
and averaged over end-effectors (the paper's `Average` is the mean of its columns), calibration error
and speed."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from eval.metrics import auc
from eval.records import FrameErrors

THRESHOLDS_M = {"1cm": 0.01, "2cm": 0.02}
SPREAD_DRAWS = 1000  # bootstrap draws of the segments behind the Average
SPREAD_SEED = 0
SPREAD_PERCENTILES = (5.0, 95.0)


def accuracy(rows: list[FrameErrors]) -> dict:
    """AUC of ADD and ADD-S at each threshold (keys like `add@1cm`), frame and failure counts."""
    out = {"n_frames": len(rows), "n_failures": sum(r.failed for r in rows)}
    for key, max_error in THRESHOLDS_M.items():
        out[f"add@{key}"] = auc([r.add_m for r in rows], max_error)
        out[f"adds@{key}"] = auc([r.adds_m for r in rows], max_error)
    return out


def _grouped(rows: list[FrameErrors], attr: str) -> dict[str, dict]:
    groups = defaultdict(list)
    for r in rows:
        groups[getattr(r, attr)].append(r)
    return {name: accuracy(group) for name, group in sorted(groups.items())}


def _stats(values: list[float]) -> dict | None:
    values = [v for v in values if not math.isnan(v)]
    if not values:
        return None
    return {"median": float(np.median(values)), "mean": float(np.mean(values))}


def _ms(values: list[float]) -> float | None:
    known = [v for v in values if v >= 0]
    return float(np.mean(known) * 1000.0) if known else None


def _calibration_at(rows: list[FrameErrors], im_id: int) -> dict | None:
    """The calibration each segment has after im_id + 1 frames (the issue's "from 15 frames")."""
    here = [r for r in rows if r.im_id == im_id]
    if not here:
        return None
    return {"n_segments": len(here), "points_mm": _stats([r.calib_points_mm for r in here]),
            "rot_deg": _stats([r.calib_rot_deg for r in here])}


def summarise(rows: list[FrameErrors]) -> dict:
    per_ee = _grouped(rows, "end_effector")
    metric_keys = [k for k in next(iter(per_ee.values())) if "@" in k]
    return {
        "n_frames": len(rows),
        "n_failures": sum(r.failed for r in rows),
        "average": {k: float(np.mean([acc[k] for acc in per_ee.values()])) for k in metric_keys},
        "average_spread": segment_spread(rows),
        "per_end_effector": per_ee,
        "per_config": _grouped(rows, "config"),
        "calibration": {"n_frames": sum(not math.isnan(r.calib_trans_mm) for r in rows),
                        "trans_mm": _stats([r.calib_trans_mm for r in rows]),
                        "rot_deg": _stats([r.calib_rot_deg for r in rows]),
                        "points_mm": _stats([r.calib_points_mm for r in rows]),
                        "frame_15": _calibration_at(rows, 14)},
        "own_masks": _own_masks(rows),
        "ms_per_frame": _ms([r.time_s for r in rows]),
        "wall_ms_per_frame": _ms([r.wall_s for r in rows]),
    }


def segment_spread(rows: list[FrameErrors], key: str = "1cm") -> dict | None:
    """Where the Average AUC@key of ADD and ADD-S falls (5th and 95th percentile) when each end-effector's
    segments are drawn again with replacement (bootstrap over segments, SPREAD_DRAWS draws, SPREAD_SEED): the
    spread a reader should expect from other segments of the same kind, so that a difference of a few points
    between runs on different data is not read as a result. None when an end-effector has one segment.

    The AUC of a set of frames is the mean of each frame's own AUC (the accuracy curve is their mean), so a
    draw sums per-segment totals instead of recomputing curves."""
    segments = defaultdict(lambda: defaultdict(list))
    for r in rows:
        segments[r.end_effector][r.scene_id].append(r)
    if any(len(per) < 2 for per in segments.values()):
        return None
    rng = np.random.default_rng(SPREAD_SEED)
    out = {"segments": sum(len(per) for per in segments.values()), "draws": SPREAD_DRAWS,
           "percentiles": list(SPREAD_PERCENTILES)}
    draws = {name: rng.integers(0, len(per), (SPREAD_DRAWS, len(per))) for name, per in sorted(segments.items())}
    for metric, attr in (("add", "add_m"), ("adds", "adds_m")):
        averages = np.zeros(SPREAD_DRAWS)
        for name, per in sorted(segments.items()):
            totals = np.array([sum(auc([getattr(r, attr)], THRESHOLDS_M[key]) for r in seg) for seg in per.values()])
            counts = np.array([len(seg) for seg in per.values()], dtype=float)
            idx = draws[name]
            averages += totals[idx].sum(1) / counts[idx].sum(1) / len(segments)
        out[f"{metric}@{key}"] = [float(v) for v in np.percentile(averages, SPREAD_PERCENTILES)]
    return out


def _own_masks(rows: list[FrameErrors]) -> dict | None:
    """The IoUs of the masks the method made itself (no mask given), over the frames it made one for."""
    if all(math.isnan(r.ee_mask_iou) and math.isnan(r.robot_mask_iou) for r in rows):
        return None
    return {"n_frames": sum(not math.isnan(r.ee_mask_iou) for r in rows),
            "ee_iou": _stats([r.ee_mask_iou for r in rows]), "robot_iou": _stats([r.robot_mask_iou for r in rows])}
