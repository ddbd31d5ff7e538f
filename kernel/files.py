"""Whole files or none: every write goes to a temp name and is `os.replace`d, so a kill or a full disk leaves
the old file or the new one; every read of a file a user may have broken is one line naming it."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np

from kernel.errors import UserError


def write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except BaseException:  # a full disk or a kill mid-write: no temp file stays behind
        tmp.unlink(missing_ok=True)
        raise


def write_png(path: Path, image: np.ndarray) -> None:
    """Encoded in memory: cv2.imwrite picks the format from the extension, which the temp name lacks."""
    _, buf = cv2.imencode(".png", image)
    write_atomic(path, buf.tobytes())


def write_gif(path: Path, images: list[np.ndarray], fps: float = 4.0) -> None:
    """An endlessly looping GIF of same-sized RGB frames."""
    data = iio.imwrite("<bytes>", np.stack(images), extension=".gif", duration=1000.0 / fps, loop=0)
    write_atomic(Path(path), data)


def read_png(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise UserError(f"{path}: not a readable PNG; delete the scene folder and write it again")
    return image


def read_json(path: Path, fix: str = "delete the scene folder and write it again", kind: type | None = dict):
    """A JSON file that a kill, a full disk or a hand edit may have broken: one line naming it. `kind`: what
    the top level must be (None: anything)."""
    try:
        content = json.loads(Path(path).read_text())
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror})") from None
    except ValueError as exc:
        raise UserError(f"{path}: not valid JSON ({exc}); {fix}") from None
    if kind is not None and not isinstance(content, kind):
        wanted = "an object" if kind is dict else f"a {kind.__name__}"
        raise UserError(f"{path}: holds a {type(content).__name__}, not {wanted}; {fix}")
    return content


def ordered(obj):
    """Dict keys in a fixed order, frame ids ("0", "1", ..., "10") as integers: BOP files run 0, 1, 2, ..."""
    if isinstance(obj, dict):
        keys = sorted(obj, key=lambda k: (0, int(k), "") if k.isdigit() else (1, 0, k))
        return {k: ordered(obj[k]) for k in keys}
    if isinstance(obj, list):
        return [ordered(v) for v in obj]
    return obj


def write_json(path: Path, content, indent: int | None = 2) -> None:
    write_atomic(path, json.dumps(ordered(content), indent=indent).encode())
