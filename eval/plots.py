"""The paper's figures: accuracy-vs-threshold curves (per run, the fraction of frames with ADD and ADD-S
<= x on [0, 1 cm], averaged over end-effectors so that the area under a curve is the Average AUC), and
the targeting plot (camera-to-base error against the number of calibration views)."""

from __future__ import annotations

import csv
import io
from collections import defaultdict
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from eval.metrics import accuracy_curve
from eval.records import FrameErrors
from syneepose.bop import write_atomic


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
