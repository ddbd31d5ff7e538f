"""Onboarding: template features lifted to 3D model points, and the BoW index over them; cached on disk.

Templates are cropped exactly like queries (square around the mask, same padding, same size), so the
object appears at the same scale on both sides of a match.
"""

from __future__ import annotations

import hashlib
import inspect
import io
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from feepe.bow import BowIndex, build_index
from feepe.crop import crop_around_mask
from feepe.depth import depth_at
from kernel.camera import backproject
from kernel.errors import UserError
from kernel.files import write_atomic
from kernel.template_set import INDEX, image_paths, read_index, read_template
from kernel.transforms import inv_T, transform_points

CACHE_VERSION = 2  # 2: the BoW assignment is stored
# the cache key holds every BoW option, defaults included, so changing a default misses the cache
BOW_DEFAULTS = {n: p.default for n, p in inspect.signature(build_index).parameters.items() if p.default is not p.empty}


@dataclass
class TemplateBank:
    ids: np.ndarray  # (T,) template ids as in templates.json
    T_cam_model: np.ndarray  # (T, 4, 4)
    offsets: np.ndarray  # (T + 1,) features of template i are rows offsets[i]:offsets[i + 1]
    uv: np.ndarray  # (M, 2) crop pixels of the template
    xyz: np.ndarray  # (M, 3) model points, metres
    desc: np.ndarray  # (M, D) float32 unit descriptors
    bow: BowIndex
    seconds: float  # onboarding time (features + BoW), as measured when built

    def features(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = slice(self.offsets[i], self.offsets[i + 1])
        return self.uv[s], self.xyz[s], self.desc[s]

    def __len__(self) -> int:
        return len(self.ids)


def default_cache_dir() -> Path:
    return Path(os.environ.get("FEEPE_CACHE", Path.home() / ".cache" / "feepe"))


def _key(folder: Path, index: dict, backbone, pad: float, bow_options: dict) -> str:
    """Hashes templates.json, the bytes of every image onboarding reads, the backbone and the options.
    Image contents rather than names, sizes and mtimes: a copied or re-checked-out set keeps its cache, and a
    re-rendered image of the same size within the file system's mtime resolution still misses; reading the
    few MB of PNGs costs little beside decoding them and running the backbone on a miss."""
    h = hashlib.sha256((folder / INDEX).read_bytes())
    for template_id in sorted(int(k) for k in index):
        for path in image_paths(folder, template_id).values():
            h.update(path.read_bytes())
    spec = {"v": CACHE_VERSION, "backbone": backbone.options(), "pad": pad, "bow": {**BOW_DEFAULTS, **bow_options}}
    h.update(json.dumps(spec, sort_keys=True).encode())
    return h.hexdigest()[:20]


def onboard(folder: Path, backbone, pad: float = 0.2, bow_options: dict | None = None,
            cache_dir: Path | None = None, progress=None) -> TemplateBank:
    """The bank of a template folder, from the cache when the templates, backbone and options match."""
    folder = Path(folder)
    index = read_index(folder)
    bow_options = dict(bow_options or {})
    cache_dir = Path(cache_dir) if cache_dir else default_cache_dir()
    path = cache_dir / f"{folder.name}-{_key(folder, index, backbone, pad, bow_options)}.npz"
    if path.is_file():
        return _load(path)
    t0 = time.perf_counter()
    ids = sorted(int(k) for k in index)
    poses, per_uv, per_xyz, per_desc = [], [], [], []
    for n, template_id in enumerate(ids):
        t = read_template(folder, template_id, index)
        uv, xyz, desc = _template_features(t, backbone, pad)
        poses.append(t.T_cam_model)
        per_uv.append(uv)
        per_xyz.append(xyz)
        per_desc.append(desc)
        if progress:
            progress(n + 1, len(ids))
    if sum(len(d) for d in per_desc) < 100:
        raise UserError(f"{folder}: the templates gave only {sum(len(d) for d in per_desc)} features; "
                        "render them larger (--resolution) or use a finer backbone stride")
    bow = build_index(per_desc, **bow_options)
    bank = TemplateBank(np.array(ids), np.stack(poses), np.cumsum([0] + [len(d) for d in per_desc]),
                        np.concatenate(per_uv), np.concatenate(per_xyz),
                        np.concatenate(per_desc).astype(np.float16).astype(np.float32), bow,  # as cached
                        time.perf_counter() - t0)
    _save(path, bank)
    return bank


def _template_features(t, backbone, pad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    crop = crop_around_mask(t.rgb, t.depth, t.mask, t.K, backbone.crop_size, pad)
    if crop is None:
        return np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 1), np.float32)
    feats = backbone.extract(crop)
    z = depth_at(crop.depth, feats.uv)
    ok = z > 0
    xyz = transform_points(inv_T(t.T_cam_model), backproject(feats.uv[ok], z[ok], crop.K))
    return feats.uv[ok], xyz, feats.desc[ok]


def _save(path: Path, bank: TemplateBank) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    bow = bank.bow
    buf = io.BytesIO()
    np.savez(buf, ids=bank.ids, T_cam_model=bank.T_cam_model, offsets=bank.offsets, uv=bank.uv, xyz=bank.xyz,
             desc=bank.desc.astype(np.float16), seconds=bank.seconds, bow_mean=bow.mean,
             bow_components=bow.components, bow_words=bow.words, bow_sigma=bow.sigma, bow_idf=bow.idf,
             bow_vectors=bow.template_vectors, bow_knn=bow.knn, bow_assignment=bow.assignment)
    write_atomic(path, buf.getvalue())


def _load(path: Path) -> TemplateBank:
    z = np.load(path)
    bow = BowIndex(z["bow_mean"], z["bow_components"], z["bow_words"], float(z["bow_sigma"]), z["bow_idf"],
                   z["bow_vectors"], int(z["bow_knn"]), str(z["bow_assignment"]))
    return TemplateBank(z["ids"], z["T_cam_model"], z["offsets"], z["uv"], z["xyz"], z["desc"].astype(np.float32),
                        bow, float(z["seconds"]))
