"""The paper's figures: accuracy-vs-threshold curves (per run, the fraction of frames with ADD and ADD-S
<= x on [0, 1 cm], averaged over end-effectors so that the area under a curve is the Average AUC), and
the targeting plot (camera-to-base error against the number of calibration views); and ours: how fast an
online method converges along its segments (accuracy and calibration error against the frame index)."""

from __future__ import annotations

import csv
import io
from collections import defaultdict
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from eval.metrics import accuracy_curve, auc
from eval.records import FrameErrors
from kernel.files import write_atomic


def save_figure(fig: Figure, path: Path) -> None:
    """The figure as a PNG, written atomically (its folder is made if missing)."""
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    write_atomic(Path(path), buf.getvalue())


def mean_curve(rows: list[FrameErrors], attr: str, max_error: float) -> tuple[np.ndarray, np.ndarray]:
    by_ee = defaultdict(list)
    for r in rows:
        by_ee[r.end_effector].append(getattr(r, attr))
    curves = [accuracy_curve(errors, max_error) for errors in by_ee.values()]
    return curves[0][0], np.mean([frac for _, frac in curves], axis=0)


def accuracy_curves(runs: list[tuple[str, list[FrameErrors]]], path: Path, max_error: float = 0.01) -> None:
    """One PNG, ADD left and ADD-S right; drawn on an Agg canvas (no display, no pyplot state)."""
    fig = Figure(figsize=(10, 4))
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2, sharey=True)
    for ax, (attr, title) in zip(axes, (("add_m", "ADD"), ("adds_m", "ADD-S"))):
        for label, rows in runs:
            x, frac = mean_curve(rows, attr, max_error)
            ax.plot(x * 100.0, frac, label=label)
        ax.set(title=title, xlabel="threshold (cm)", xlim=(0, max_error * 100.0), ylim=(0, 1.02), ylabel="accuracy")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize="small")
    save_figure(fig, path)


def frame_bins(im_ids: np.ndarray, n_bins: int = 8) -> list[tuple[int, int]]:
    """Consecutive frame-index ranges [first, last] of equal width covering 0..max(im_ids)."""
    last = int(np.max(im_ids))
    width = max(1, int(np.ceil((last + 1) / n_bins)))
    return [(a, min(a + width - 1, last)) for a in range(0, last + 1, width)]


def convergence(rows: list[FrameErrors], bins: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """Per frame-index range: AUC@1cm of ADD averaged over end-effectors, and the median camera-to-base
    translation error (mm; NaN where no frame has a calibration)."""
    add_auc, calib = [], []
    for a, b in bins:
        here = [r for r in rows if a <= r.im_id <= b]
        ees = sorted({r.end_effector for r in here})
        add_auc.append(np.mean([auc([r.add_m for r in here if r.end_effector == e], 0.01) for e in ees])
                       if ees else np.nan)
        known = [r.calib_trans_mm for r in here if np.isfinite(r.calib_trans_mm)]
        calib.append(np.median(known) if known else np.nan)
    return np.array(add_auc), np.array(calib)


def convergence_plot(runs: list[tuple[str, list[FrameErrors]]], path: Path, n_bins: int = 8) -> None:
    """AUC@1cm ADD (left) and median calibration error (right, log) per frame-index range."""
    fig = Figure(figsize=(10, 4))
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    bins = frame_bins(np.array([r.im_id for _, rows in runs for r in rows]), n_bins)
    centres = [(a + b) / 2 for a, b in bins]
    for label, rows in runs:
        add_auc, calib = convergence(rows, bins)
        axes[0].plot(centres, add_auc, marker="o", label=label)
        axes[1].plot(centres, calib, marker="o", label=label)
    axes[0].set(title="AUC@1cm ADD by frame index", xlabel="frame index", ylabel="AUC (%)", ylim=(0, 100))
    axes[1].set(title="camera-to-base error by frame index", xlabel="frame index", ylabel="median error (mm)",
                yscale="log")
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize="small")
    save_figure(fig, path)


def read_trials(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return [{**row, "views": int(row["views"]), "points_mm": float(row["points_mm"]),
                 "rot_deg": float(row["rot_deg"])} for row in csv.DictReader(f)]


def targeting_plot(trial_sets: list[list[dict]], path: Path) -> None:
    """Median (line) and every trial (dots) of the workspace-point error and the rotation error."""
    fig = Figure(figsize=(10, 4))
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    trials = [t for ts in trial_sets for t in ts]
    methods = sorted({t["method"] for t in trials})
    for ax, (key, title) in zip(axes, (("points_mm", "error at 5 workspace points (mm)"),
                                       ("rot_deg", "rotation error (deg)"))):
        for k, method in enumerate(methods):
            mine = [t for t in trials if t["method"] == method and np.isfinite(t[key])]
            views = sorted({t["views"] for t in mine})
            median = [np.median([t[key] for t in mine if t["views"] == v]) for v in views]
            line, = ax.plot(views, median, marker="o", label=method)
            ax.scatter([t["views"] + 0.15 * (k - 0.5) for t in mine], [t[key] for t in mine], s=8, alpha=0.4,
                       color=line.get_color())
        ax.set(xlabel="views", title=title, yscale="log")
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize="small")
    save_figure(fig, path)
