"""The BOP results CSV (`scene_id,im_id,obj_id,score,R,t,time`): what MegaPose, SAM-6D and FoundationPose
write, so the evaluator scores peers it cannot run. R row-major, t in mm, time in s (-1 unknown)."""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from kernel.errors import UserError
from kernel.files import write_atomic
from kernel.transforms import make_T

HEADER = "scene_id,im_id,obj_id,score,R,t,time"
ROTATION_TOL = 1e-3  # |R R^T - I| and |det R - 1|: 6 printed digits pass, a wrong matrix does not


@dataclass
class BopResult:
    scene_id: int
    im_id: int
    obj_id: int
    score: float
    T_cam_ee: np.ndarray  # (4, 4) metres
    time_s: float = -1.0


def _numbers(values: Iterable[float]) -> str:
    return " ".join(repr(float(v)) for v in values)


def write_results(path: Path, results: Iterable[BopResult]) -> None:
    out = io.StringIO()
    out.write(HEADER + "\n")
    for r in results:
        T = np.asarray(r.T_cam_ee, dtype=float)
        out.write(f"{r.scene_id},{r.im_id},{r.obj_id},{float(r.score)!r},{_numbers(T[:3, :3].ravel())},"
                  f"{_numbers(T[:3, 3] * 1000.0)},{float(r.time_s)!r}\n")
    write_atomic(Path(path), out.getvalue().encode())


def _parse(fields: list[str], where: str) -> BopResult:
    try:
        scene_id, im_id, obj_id = (int(v) for v in fields[:3])
        score, time_s = float(fields[3]), float(fields[6])
        R = np.array(fields[4].split(), dtype=float)
        t = np.array(fields[5].split(), dtype=float)
    except ValueError as exc:
        raise UserError(f"{where}: not a number ({exc}); columns are {HEADER}") from None
    if R.size != 9 or t.size != 3:
        raise UserError(f"{where}: R needs 9 and t 3 space-separated values, got {R.size} and {t.size}")
    if not (np.isfinite(R).all() and np.isfinite(t).all() and np.isfinite(score)):
        raise UserError(f"{where}: R, t and score must be finite numbers")
    R = R.reshape(3, 3)
    if np.abs(R @ R.T - np.eye(3)).max() > ROTATION_TOL or abs(np.linalg.det(R) - 1.0) > ROTATION_TOL:
        raise UserError(f"{where}: R is not a rotation matrix (orthonormal, det +1, to {ROTATION_TOL}); "
                        "write R row-major")
    return BopResult(scene_id, im_id, obj_id, score, make_T(R, t / 1000.0), time_s)


def read_results(path: Path, obj_ids: Iterable[int] | None = None,
                 scene_ids: Iterable[int] | None = None) -> dict[tuple[int, int, int], BopResult]:
    """Estimates by (scene_id, im_id, obj_id); of duplicates the highest score wins (as in BOP).

    `obj_ids` / `scene_ids`, when given, are the ones the data set has: any other is an error."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: results file not found")
    obj_ids = None if obj_ids is None else set(obj_ids)
    scene_ids = None if scene_ids is None else set(scene_ids)
    lines = path.read_text().splitlines()
    if not lines or lines[0].strip() != HEADER:
        raise UserError(f"{path}:1: expected the BOP header {HEADER!r}")
    out: dict[tuple[int, int, int], BopResult] = {}
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        where = f"{path}:{number}"
        fields = line.split(",")
        if len(fields) != 7:
            raise UserError(f"{where}: {len(fields)} columns, expected 7 ({HEADER})")
        r = _parse(fields, where)
        if obj_ids is not None and r.obj_id not in obj_ids:
            raise UserError(f"{where}: obj_id {r.obj_id} is not in the data set (known: {sorted(obj_ids)})")
        if scene_ids is not None and r.scene_id not in scene_ids:
            raise UserError(f"{where}: scene {r.scene_id} is not in the data set ({len(scene_ids)} scenes, "
                            f"ids {min(scene_ids, default=None)}..{max(scene_ids, default=None)})")
        key = (r.scene_id, r.im_id, r.obj_id)
        if key not in out or r.score > out[key].score:
            out[key] = r
    return out
