"""A FEEPE template set on disk: one folder per end-effector, `<ee>_<views>x<inplane>_<res>px/`, holding
`rgb/`, `depth/`, `mask/` (`<id:06d>.png`, depth in `depth_scale` mm units, 0 off the object) and
`templates.json` ({id: view, inplane, cam_K, T_cam_model (metres), depth_scale, obj_id, samples, inplane_by:
rotated | rendered, denoise_prefilter: fast | accurate}).
The generator writes sets (`python -m syneepose templates`); the estimator only reads them."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kernel.bop import DEPTH_DIR, DEPTH_SCALE, MASK_DIR, RGB_DIR, image_path
from kernel.dataset import TEMPLATES
from kernel.errors import UserError
from kernel.files import read_json, read_png, write_atomic, write_png

INDEX = "templates.json"
IMAGES = (RGB_DIR, DEPTH_DIR, MASK_DIR)  # a template's image folders, named as a scene's


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
    return Path(root) / TEMPLATES / f"{ee}_{n_views}x{n_inplane}_{resolution}px"


def image_paths(folder: Path, template_id: int) -> dict[str, Path]:
    """A template's images by folder (`<folder>/rgb/<id:06d>.png`, ...): what `read_template` reads, the writer
    writes and FEEPE's onboarding hashes for its cache."""
    return {kind: image_path(folder, kind, template_id) for kind in IMAGES}


_SET = re.compile(r"^(?P<ee>.+)_(?P<views>\d+)x(?P<inplane>\d+)_(?P<res>\d+)px$")


def find_template_set(root: Path, ee: str, n_templates: int | None) -> Path:
    """The set of `ee` under a templates folder (`set_dir` names): `n_templates` of them, or the largest
    count, then the largest resolution."""
    sets = []
    for p in sorted(Path(root).glob(f"{ee}_*")):
        m = _SET.match(p.name)
        if m and m["ee"] == ee and (p / INDEX).is_file():
            sets.append((int(m["views"]) * int(m["inplane"]), int(m["res"]), p))
    if n_templates is not None:
        sets = [s for s in sets if s[0] == n_templates]
    if not sets:
        wanted = f"{n_templates} templates" if n_templates else "templates"
        raise UserError(f"no {wanted} for {ee} in {root}; render them with `python -m syneepose templates --out "
                        f"DATASET --ee {ee}` (--views x --inplane = the count)")
    return max(sets)[2]


def read_index(folder: Path) -> dict:
    path = Path(folder) / INDEX
    if not path.is_file():
        raise UserError(f"no template set at {folder}: render it with `python -m syneepose templates`")
    return read_json(path, "delete the template set folder and render it again")


def check_recipe(folder: Path, samples: int, inplane: str, complete: bool, prefilter: str) -> None:
    """A set is made one way: one sample count, one way to make in-plane rotations (`inplane_by`, "rendered"
    for sets from before it was recorded) and one denoiser prefilter ("accurate" before it was recorded); a
    rerun that asks for another would mix two kinds of template. A complete set made another way is used as
    it is (rendered rotations are the exact reference)."""
    if not (Path(folder) / INDEX).is_file():
        return
    records = read_index(folder).values()
    other = sorted({r["samples"] for r in records if r.get("samples", samples) != samples})
    if other:
        raise UserError(f"{folder} was rendered with --samples {other[0]}, not {samples}; rerun with --samples "
                        f"{other[0]} to resume, or delete the folder to render it again")
    other = sorted({r.get("inplane_by", "rendered") for r in records} - {inplane})
    if other and not complete:
        raise UserError(f"{folder} holds in-plane rotations {other[0]}, not {inplane}; rerun with --inplane-by "
                        f"{other[0]} to resume, or delete the folder to render it again")
    other = sorted({r.get("denoise_prefilter", "accurate") for r in records} - {prefilter})
    if other and not complete:
        raise UserError(f"{folder} was denoised with the {other[0]} prefilter of an older SynEEPose, not today's "
                        f"{prefilter}; delete the folder to render it again")


def read_template(folder: Path, template_id: int, index: dict | None = None) -> Template:
    """One template; pass the set's `read_index` when reading many, so the index is parsed once."""
    index = read_index(folder) if index is None else index
    rec = index.get(str(template_id))
    if rec is None:
        raise UserError(f"{folder}: no template {template_id}")
    paths = image_paths(folder, template_id)
    rgb = read_png(paths[RGB_DIR])[..., ::-1]
    return Template(template_id, rec["view"], rec["inplane"], np.array(rec["cam_K"]).reshape(3, 3),
                    np.array(rec["T_cam_model"]), np.ascontiguousarray(rgb),
                    read_png(paths[DEPTH_DIR]) * (rec["depth_scale"] / 1000.0), read_png(paths[MASK_DIR]) > 127)


class TemplateSetWriter:
    """Adds templates to a set, resumable: images first, then the index, so the index names only whole
    templates; `done(id)` says which a killed run finished. `write` takes a batch (a view's in-plane
    rotations) and rewrites the index once for it: rewriting it per template made a 960-template set spend
    a third of its time serialising the growing index."""

    def __init__(self, folder: Path, obj_id: int, samples: int, inplane_by: str, prefilter: str):
        self.folder, self.obj_id, self.samples, self.inplane_by = Path(folder), obj_id, samples, inplane_by
        self.prefilter = prefilter
        self.index = read_index(self.folder) if (self.folder / INDEX).is_file() else {}
        for sub in IMAGES:
            (self.folder / sub).mkdir(parents=True, exist_ok=True)

    def done(self, template_id: int) -> bool:
        return str(template_id) in self.index

    def write(self, templates: list[Template]) -> None:
        for template in templates:  # the index file is written after all of the batch's images
            paths = image_paths(self.folder, template.id)
            write_png(paths[RGB_DIR], np.ascontiguousarray(template.rgb[..., ::-1]))
            write_png(paths[DEPTH_DIR], np.round(template.depth * 1000.0 / DEPTH_SCALE).astype(np.uint16))
            write_png(paths[MASK_DIR], template.mask.astype(np.uint8) * 255)
            self.index[str(template.id)] = {
                "view": template.view, "inplane": template.inplane, "cam_K": template.K.ravel().tolist(),
                "T_cam_model": template.T_cam_model.tolist(), "depth_scale": DEPTH_SCALE, "obj_id": self.obj_id,
                "samples": self.samples, "inplane_by": self.inplane_by, "denoise_prefilter": self.prefilter}
        write_atomic(self.folder / INDEX, json.dumps(self.index, indent=2, sort_keys=True).encode())
