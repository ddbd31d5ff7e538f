"""The evaluation model that ADD / ADD-S are computed on, as the BOP toolkit does: every vertex of the data
set's `models_eval/obj_XXXXXX.ply` (uniformly resampled, no duplicate vertices; mm -> m).

BOP (bop_toolkit_lib.pose_error `add` / `adi`; Hinterstoisser et al., ACCV 2012; Hodan et al., ECCV 2018)
averages over all vertices and searches the ADD-S nearest neighbour over all vertices. Ours searches over
all vertices too (one cKDTree per model). Only the mean may run over a subset (the query side): the model
is cut into cubic cells, each cell's vertex nearest its centroid stands for the cell and is weighted by the
cell's vertex count, which estimates BOP's mean over all vertices far more closely than a random subset
of the same size (measured: README, tests/test_eval_metrics.py). `max_query=None` gives BOP's number exactly.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from eval.metrics import model_tree
from syneepose.errors import UserError

MODELS_EVAL = "models_eval"
MAX_QUERY = 4000  # query vertices per model: AUC within 0.1 of all vertices (tests), cost in benchmarks/metrics.py


@dataclass
class EvalModel:
    obj_id: int
    vertices: np.ndarray  # (n, 3) metres: every vertex of the PLY, the ADD-S search set
    query: np.ndarray  # (q, 3) metres: the points the means run over (all vertices unless subsampled)
    weights: np.ndarray | None  # (q,) summing to 1 for a subset; None = plain mean over all vertices
    tree: cKDTree  # over `vertices`
    sha256: str  # of the PLY file, so a run knows when the model it was scored on changed

    @property
    def subsampled(self) -> bool:
        return len(self.query) < len(self.vertices)


def _cells(vertices: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Cell index of every vertex on a cubic grid of `size` metres, and the vertex count of each cell."""
    keys = np.floor((vertices - vertices.min(axis=0)) / size).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    return inverse.ravel(), counts


def query_subset(vertices: np.ndarray, max_query: int | None) -> tuple[np.ndarray, np.ndarray | None]:
    """At most `max_query` vertices, one per occupied cell of the finest grid that has no more cells, each
    weighted by its cell's share of the vertices; all vertices (weights None) when None or fewer."""
    if max_query is None or len(vertices) <= max_query:
        return vertices, None
    lo, hi = np.log(np.ptp(vertices, axis=0).max() * 1e-4), np.log(np.ptp(vertices, axis=0).max())
    for _ in range(40):  # bisection on log cell size: the cell count falls as the cells grow
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if len(_cells(vertices, np.exp(mid))[1]) > max_query else (lo, mid)
    cell, counts = _cells(vertices, np.exp(hi))
    centroids = np.stack([np.bincount(cell, vertices[:, i]) for i in range(3)], axis=1) / counts[:, None]
    order = np.lexsort((np.linalg.norm(vertices - centroids[cell], axis=1), cell))
    nearest = order[np.r_[0, np.flatnonzero(np.diff(cell[order])) + 1]]
    return vertices[nearest], counts[cell[nearest]] / len(vertices)


def symmetries_m(info: dict) -> list[np.ndarray]:
    """The discrete symmetries of a models_info.json entry as 4x4 matrices in metres."""
    out = []
    for flat in info.get("symmetries_discrete", []):
        S = np.array(flat, dtype=float).reshape(4, 4)
        S[:3, 3] /= 1000.0
        out.append(S)
    return out


def load_eval_model(dataset: Path, obj_id: int, max_query: int | None = MAX_QUERY) -> EvalModel:
    folder = Path(dataset) / MODELS_EVAL
    ply, info_path = folder / f"obj_{obj_id:06d}.ply", folder / "models_info.json"
    for path in (ply, info_path):
        if not path.is_file():
            raise UserError(f"{path}: missing; pose errors are computed on the data set's {MODELS_EVAL}/ (BOP); "
                            "rerun the render command that wrote the data set (it resumes and adds missing files)")
    if str(obj_id) not in json.loads(info_path.read_text()):
        raise UserError(f"{info_path}: no entry for obj_id {obj_id}; rebuild the models (python -m syneepose assets)")
    data = ply.read_bytes()
    vertices = np.asarray(trimesh.load(ply, file_type="ply", process=False).vertices, dtype=float) / 1000.0
    if len(vertices) == 0:
        raise UserError(f"{ply}: no vertices; rebuild the models (python -m syneepose assets)")
    query, weights = query_subset(vertices, max_query)
    return EvalModel(obj_id=obj_id, vertices=vertices, query=query, weights=weights, tree=model_tree(vertices),
                     sha256=hashlib.sha256(data).hexdigest())
