"""Accuracy-vs-threshold curves (the paper's curve figure): per run, the fraction of frames with ADD and
ADD-S <= x on [0, 1 cm], averaged over end-effectors so that the area under a curve is the Average AUC."""

from __future__ import annotations

import io
from collections import defaultdict
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from eval.metrics import accuracy_curve
from eval.records import FrameErrors
from syneepose.bop import write_atomic


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
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    write_atomic(Path(path), buf.getvalue())
