"""The points ADD / ADD-S are measured on: the unique vertices of a data set's BOP model (mm -> m).

Models with more than MAX_POINTS unique vertices are subsampled with a fixed seed. A plain random
subsample would break the model's symmetries (the partner of a kept vertex is often dropped, which
raises ADD-S under an exact symmetry from 0.05 to 0.9 mm on the 2F-85), so every drawn vertex brings
its images under the model's discrete symmetries (nearest vertex) along.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from syneepose.errors import UserError
from syneepose.transforms import transform_points

MAX_POINTS = 2000  # keeps 54,000 frames of ADD-S near a minute on 2 cores (benchmarks/metrics.py)
SEED = 0


@dataclass
class ModelPoints:
    obj_id: int
    points: np.ndarray  # (n, 3) metres
    n_vertices: int  # in the PLY, duplicates included
    n_unique: int
    subsampled: bool


def symmetric_subsample(points: np.ndarray, symmetries: list[np.ndarray], max_points: int,
                        seed: int = SEED) -> np.ndarray:
    """At most `max_points` of `points`, closed under `symmetries` (4x4, metres) up to the nearest vertex."""
    if len(points) <= max_points:
        return points
    drawn = np.random.default_rng(seed).choice(len(points), max_points // (1 + len(symmetries)), replace=False)
    tree = cKDTree(points)
    images = [tree.query(transform_points(S, points[drawn]))[1] for S in symmetries]
    return points[np.unique(np.concatenate([drawn, *images]))]


def symmetries_m(info: dict) -> list[np.ndarray]:
    out = []
    for flat in info.get("symmetries_discrete", []):
        S = np.array(flat, dtype=float).reshape(4, 4)
        S[:3, 3] /= 1000.0
        out.append(S)
    return out


def load_model_points(models_dir: Path, obj_id: int, max_points: int = MAX_POINTS) -> ModelPoints:
    models_dir = Path(models_dir)
    ply, info_path = models_dir / f"obj_{obj_id:06d}.ply", models_dir / "models_info.json"
    for path in (ply, info_path):
        if not path.is_file():
            raise UserError(f"{path}: missing; the data set's models/ folder must hold the BOP models "
                            "(the renderer copies them there)")
    info = json.loads(info_path.read_text()).get(str(obj_id))
    if info is None:
        raise UserError(f"{info_path}: no entry for obj_id {obj_id}; rebuild the models (python -m syneepose assets)")
    vertices = np.asarray(trimesh.load(ply, process=False).vertices, dtype=float) / 1000.0
    unique = np.unique(vertices, axis=0)
    points = symmetric_subsample(unique, symmetries_m(info), max_points)
    return ModelPoints(obj_id=obj_id, points=points, n_vertices=len(vertices), n_unique=len(unique),
                       subsampled=len(points) < len(unique))
