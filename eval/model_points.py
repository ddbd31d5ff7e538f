"""The evaluation model that ADD / ADD-S are computed on, as the BOP toolkit does: every vertex of the data
set's `models_eval/obj_XXXXXX.ply` (uniformly resampled, no duplicate vertices; mm -> m).

BOP (bop_toolkit_lib.pose_error `add` / `adi`; Hinterstoisser et al., ACCV 2012; Hodan et al., ECCV 2018)
averages over all vertices and searches the ADD-S nearest neighbour over all vertices. Ours searches over
all vertices too (one kd-tree per model). Only the mean may run over a subset (the query side), by
stratified sampling: the model is cut into cubic cells, and for each frame one vertex is drawn at random
in every cell and weighted by the cell's share of the vertices. Its expectation is BOP's mean over all
vertices, and the draws are independent between frames, so the errors of single frames average out of
an AUC. A fixed representative per cell (the vertex nearest its centroid, our first version) was biased
low on ADD-S by about 10 um at 4000 cells, enough to move AUC@1cm by 0.1 on the Shadow Hand (docs/eval.md "Metric cost",
tests/test_eval_metrics.py). `max_query=None` gives BOP's number exactly.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from eval.metrics import KDTree, model_tree
from kernel.dataset import MODELS_EVAL, MODELS_INFO, Dataset
from kernel.errors import UserError
from kernel.files import read_json

MAX_QUERY = 1000  # cells, one query vertex drawn in each per frame: tests/test_eval_metrics.py, benchmarks/
QUERY_SEED = 0  # with the frame's key, seeds the frame's draw: a frame scores the same whatever is scored with it
QUERY_RULE = {"models": MODELS_EVAL, "max_query": MAX_QUERY, "query": "one vertex drawn per grid cell and frame",
              "query_seed": QUERY_SEED}  # in each scene's fingerprint: a changed rule re-scores stored estimates
QUERY_RULE_TEXT = (f"every vertex of {MODELS_EVAL}/obj_XXXXXX.ply (mm -> m) is searched for the ADD-S nearest "
                   f"neighbour; the means run over at most {MAX_QUERY} of them, one drawn at random per cell of a "
                   "cubic grid and frame, weighted by the cell's vertex count (an unbiased estimate of BOP's mean "
                   "over all, seeded by scene and image id)")


@dataclass(frozen=True)
class QueryCells:
    """The model's vertex indices grouped by cubic cell: cell c holds order[starts[c] : starts[c] + counts[c]]."""

    order: np.ndarray
    starts: np.ndarray
    counts: np.ndarray

    @property
    def weights(self) -> np.ndarray:
        return self.counts / self.counts.sum()


@dataclass
class EvalModel:
    obj_id: int
    vertices: np.ndarray  # (n, 3) metres: every vertex of the PLY, the ADD-S search set
    tree: KDTree  # over `vertices`
    sha256: str  # of the PLY file, so a run knows when the model it was scored on changed
    cells: QueryCells | None  # the query strata; None = the means run over every vertex

    @property
    def subsampled(self) -> bool:
        return self.cells is not None

    @property
    def n_query(self) -> int:
        return len(self.vertices) if self.cells is None else len(self.cells.counts)

    def query_points(self, keys) -> tuple[np.ndarray, np.ndarray | None]:
        """The points the means run over for frames named by integer `keys` (e.g. (scene_id, im_id) each):
        (n, q, 3) vertices, one drawn per cell from a generator seeded by the frame's key, and the cells'
        weights (q,); every vertex (q, 3) and weights None when not subsampled."""
        if self.cells is None:
            return self.vertices, None
        c = self.cells
        u = np.array([np.random.default_rng([QUERY_SEED, *np.atleast_1d(key)]).random(len(c.counts))
                      for key in keys]).reshape(-1, len(c.counts))
        picks = c.order[c.starts + np.minimum((u * c.counts).astype(np.int64), c.counts - 1)]
        return self.vertices[picks], c.weights


def _cells(vertices: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Cell index of every vertex on a cubic grid of `size` metres, and the vertex count of each cell."""
    keys = np.floor((vertices - vertices.min(axis=0)) / size).astype(np.int64)
    extent = keys.max(axis=0) + 1
    # one integer per cell, ordered as its (x, y, z) rows: np.unique's axis=0 order at a tenth of the cost
    flat = (keys[:, 0] * extent[1] + keys[:, 1]) * extent[2] + keys[:, 2]
    _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    return inverse.ravel(), counts


def query_cells(vertices: np.ndarray, max_query: int | None) -> QueryCells | None:
    """The finest cubic grid with at most `max_query` occupied cells; None (every vertex) when max_query is
    None or the model has no more vertices than that."""
    if max_query is None or len(vertices) <= max_query:
        return None
    lo, hi = np.log(np.ptp(vertices, axis=0).max() * 1e-4), np.log(np.ptp(vertices, axis=0).max())
    for _ in range(40):  # bisection on log cell size: the cell count falls as the cells grow
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if len(_cells(vertices, np.exp(mid))[1]) > max_query else (lo, mid)
    cell, counts = _cells(vertices, np.exp(hi))
    return QueryCells(order=np.argsort(cell, kind="stable"), starts=np.r_[0, np.cumsum(counts)[:-1]],
                      counts=counts)


def symmetries_m(info: dict) -> list[np.ndarray]:
    """The discrete symmetries of a models_info.json entry as 4x4 matrices in metres."""
    out = []
    for flat in info.get("symmetries_discrete", []):
        S = np.array(flat, dtype=float).reshape(4, 4)
        S[:3, 3] /= 1000.0
        out.append(S)
    return out


def load_eval_model(dataset: Path, obj_id: int, max_query: int | None = MAX_QUERY) -> EvalModel:
    layout = Dataset(Path(dataset))
    ply, info_path = layout.eval_model_path(obj_id), layout.models_eval_dir / MODELS_INFO
    for path in (ply, info_path):
        if not path.is_file():
            raise UserError(f"{path}: missing; pose errors are computed on the data set's {MODELS_EVAL}/ (BOP); "
                            "rerun the render command that wrote the data set (it resumes and adds missing files)")
    if str(obj_id) not in read_json(info_path, "rebuild the models (python -m syneepose assets)"):
        raise UserError(f"{info_path}: no entry for obj_id {obj_id}; rebuild the models (python -m syneepose assets)")
    data = ply.read_bytes()
    vertices = np.asarray(trimesh.load(ply, file_type="ply", process=False).vertices, dtype=float) / 1000.0
    if len(vertices) == 0:
        raise UserError(f"{ply}: no vertices; rebuild the models (python -m syneepose assets)")
    return EvalModel(obj_id=obj_id, vertices=vertices, tree=model_tree(vertices),
                     sha256=hashlib.sha256(data).hexdigest(), cells=query_cells(vertices, max_query))
