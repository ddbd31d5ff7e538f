"""FEEPE templates: views on a Fibonacci sphere x in-plane rotations, object centred (pure numpy).

Rendering lives in `syneepose/blender/templates.py`; this module decides poses and intrinsics and
reads a template set back. A set is one folder per end-effector with BOP-style files:
`rgb/`, `depth/`, `mask/` (`<id:06d>.png`) and `templates.json` ({id: cam_K, T_cam_model, view, inplane}).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from syneepose.bop import read_json, read_png
from syneepose.errors import UserError
from syneepose.scene.sample import look_at
from syneepose.transforms import inv_T, make_T

FOV_DEG = 30.0
FILL = 0.9  # the bounding sphere spans this fraction of the image width


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z**2)
    phi = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def intrinsics(resolution: int) -> np.ndarray:
    f = resolution / 2 / np.tan(np.deg2rad(FOV_DEG) / 2)
    c = (resolution - 1) / 2
    return np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])


def poses(n_views: int, n_inplane: int, center: np.ndarray, radius: float) -> list[tuple[int, int, np.ndarray]]:
    """(view, inplane, T_cam_model) with the model's bounding-sphere centre on the optical axis."""
    distance = radius / np.sin(np.deg2rad(FOV_DEG) / 2 * FILL)
    out = []
    for v, direction in enumerate(fibonacci_sphere(n_views)):
        up = (0.0, 0.0, 1.0) if abs(direction[2]) < 0.99 else (1.0, 0.0, 0.0)
        T_model_cam = look_at(center + distance * direction, center, up)
        for k in range(n_inplane):
            a = 2 * np.pi * k / n_inplane
            roll = make_T(np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]]))
            out.append((v, k, inv_T(T_model_cam @ roll)))
    return out


@dataclass
class Template:
    id: int
    view: int
    inplane: int
    K: np.ndarray
    T_cam_model: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray  # metres, 0 off the object
    mask: np.ndarray


def set_dir(root: Path, ee: str, n_views: int, n_inplane: int, resolution: int) -> Path:
    return Path(root) / "templates" / f"{ee}_{n_views}x{n_inplane}_{resolution}px"


_SET = re.compile(r"^(?P<ee>.+)_(?P<views>\d+)x(?P<inplane>\d+)_(?P<res>\d+)px$")


def find_template_set(root: Path, ee: str, n_templates: int | None) -> Path:
    """The set of `ee` under a templates folder (`set_dir` names): `n_templates` of them, or the largest
    count, then the largest resolution."""
    sets = []
    for p in sorted(Path(root).glob(f"{ee}_*")):
        m = _SET.match(p.name)
        if m and m["ee"] == ee and (p / "templates.json").is_file():
            sets.append((int(m["views"]) * int(m["inplane"]), int(m["res"]), p))
    if n_templates is not None:
        sets = [s for s in sets if s[0] == n_templates]
    if not sets:
        wanted = f"{n_templates} templates" if n_templates else "templates"
        raise UserError(f"no {wanted} for {ee} in {root}; render them with `python -m syneepose templates --out "
                        f"DATASET --ee {ee}` (--views x --inplane = the count)")
    return max(sets)[2]


def read_index(folder: Path) -> dict:
    path = Path(folder) / "templates.json"
    if not path.is_file():
        raise UserError(f"no template set at {folder}: render it with `python -m syneepose templates`")
    return read_json(path, "delete the template set folder and render it again")


def check_samples(folder: Path, samples: int) -> None:
    """A set is rendered with one sample count: a rerun that asks for another would mix two noise levels."""
    if not (Path(folder) / "templates.json").is_file():
        return
    other = sorted({r["samples"] for r in read_index(folder).values() if r.get("samples", samples) != samples})
    if other:
        raise UserError(f"{folder} was rendered with --samples {other[0]}, not {samples}; rerun with --samples "
                        f"{other[0]} to resume, or delete the folder to render it again")


def read_template(folder: Path, template_id: int, index: dict | None = None) -> Template:
    """One template; pass the set's `read_index` when reading many, so the index is parsed once."""
    index = read_index(folder) if index is None else index
    rec = index.get(str(template_id))
    if rec is None:
        raise UserError(f"{folder}: no template {template_id}")
    name = f"{template_id:06d}.png"
    rgb = read_png(Path(folder) / "rgb" / name)[..., ::-1]
    return Template(template_id, rec["view"], rec["inplane"], np.array(rec["cam_K"]).reshape(3, 3),
                    np.array(rec["T_cam_model"]), np.ascontiguousarray(rgb),
                    read_png(Path(folder) / "depth" / name) * (rec["depth_scale"] / 1000.0),
                    read_png(Path(folder) / "mask" / name) > 127)
