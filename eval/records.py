"""errors.csv: one row per evaluated frame, the input of the summary, the tables and the curves.

A failed frame (no estimate) has add_m = adds_m = inf and empty pose errors and score; calibration
columns are empty when the method gives no camera-to-base pose."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, fields
from pathlib import Path

from kernel.errors import UserError
from kernel.files import write_atomic


@dataclass
class FrameErrors:
    scene_id: int
    im_id: int
    obj_id: int
    config: str
    end_effector: str
    add_m: float
    adds_m: float
    rot_err_deg: float
    trans_err_mm: float
    calib_trans_mm: float
    calib_rot_deg: float
    time_s: float  # the method's own time (BOP `time`), -1 unknown
    score: float
    wall_s: float  # the runner's clock around the method's `estimate` call
    calib_points_mm: float = math.nan  # calibration error at eval.metrics.WORKSPACE_POINTS (mean distance)
    ee_mask_iou: float = math.nan  # the method's own end-effector mask against mask_visib/ (none made: empty)
    robot_mask_iou: float = math.nan  # the method's own robot mask against the robot's visible mask

    @property
    def failed(self) -> bool:
        return math.isinf(self.add_m)


COLUMNS = [f.name for f in fields(FrameErrors)]
ADDED = ("calib_points_mm", "ee_mask_iou", "robot_mask_iou")  # columns later than the first errors.csv files:
# absent reads as unknown
_INTS, _STRS = {"scene_id", "im_id", "obj_id"}, {"config", "end_effector"}


def _cell(value) -> str:
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


def write_errors(path: Path, rows: list[FrameErrors]) -> None:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(COLUMNS)
    for row in rows:
        writer.writerow([_cell(getattr(row, name)) for name in COLUMNS])
    write_atomic(Path(path), out.getvalue().encode())


def _value(name: str, text: str):
    if name in _INTS:
        return int(text)
    if name in _STRS:
        return text
    return float(text) if text else math.nan


def read_errors(path: Path) -> list[FrameErrors]:
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: missing; it is written by python -m eval.run")
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        names = reader.fieldnames or []
        if names != [c for c in COLUMNS if c in names] or not set(COLUMNS) - set(names) <= set(ADDED):
            raise UserError(f"{path}: columns {reader.fieldnames} are not those of python -m eval.run; run it again")
        try:
            return [FrameErrors(**{name: _value(name, row[name]) for name in names}) for row in reader]
        except (TypeError, ValueError) as exc:
            raise UserError(f"{path}:{reader.line_num}: {exc}; run python -m eval.run again") from None
