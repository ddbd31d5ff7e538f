"""One frame, no history: crop, features, top-K_r templates by BoW, best-buddy matches, PnP per template.

Each reference template gives a candidate: its pose and its PnP-inlier 2D-3D matches, with the query
depth at the matched pixels kept for the 3D term of the optimisation. Coordinates stay in crop pixels
with the crop intrinsics, so reprojection errors mean the same for near and far end-effectors.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from feepe.crop import Crop, crop_around_mask
from feepe.depth import depth_at
from feepe.icp import SurfaceModel
from feepe.matching import best_buddies
from feepe.onboarding import TemplateBank
from feepe.pnp import solve_pnp
from feepe.segmentation import Segmentation
from feepe.silhouette import MaskView
from kernel.camera import backproject
from kernel.errors import UserError


@dataclass
class Candidate:
    template: int  # row in the bank
    T_cam_ee: np.ndarray  # (4, 4)
    uv: np.ndarray  # (n, 2) inlier query points, crop pixels
    xyz: np.ndarray  # (n, 3) their model points, metres
    observed: np.ndarray  # (n, 3) query depth back-projected at uv (NaN rows where depth is 0)
    retrieval: float  # BoW cosine similarity of the template

    @property
    def n_inliers(self) -> int:
        return len(self.uv)


@dataclass
class FrameCandidates:
    K: np.ndarray  # (3, 3) crop intrinsics
    candidates: list[Candidate]
    n_features: int
    timings: dict = field(default_factory=dict)  # ms per stage
    cloud: np.ndarray | None = None  # (N, 3) masked depth points, camera frame (depth alignment only)
    surface: SurfaceModel | None = None  # what the cloud shows, placed in the base frame (no mask given: the
    # robot at this frame's joint states); None: the end-effector's model, at the frame's T_base_ee
    silhouette: MaskView | None = None  # the frame's mask as a distance field (silhouette refinement only)
    parts: np.ndarray | None = None  # (n, 4, 4) T_base of the parts that mask shows: the end-effector (, the arm links)
    robot_starts: list = field(default_factory=list)  # T_cam_base starts from the robot's depth (first frames)
    segmentation: Segmentation | None = None  # no mask given: the estimator's own (feepe/segmentation.py)


@dataclass
class SingleFrameOptions:
    pad: float = 0.2
    k_r: int = 5
    max_matches: int = 300
    pnp_threshold_px: float = 4.0  # crop pixels
    pnp_iterations: int = 100
    min_mask_px: int = 64

    def __post_init__(self):
        for name, low in (("k_r", 1), ("max_matches", 4), ("pnp_iterations", 1), ("min_mask_px", 1)):
            if not getattr(self, name) >= low:
                raise UserError(f"SingleFrameOptions.{name} = {getattr(self, name)} must be >= {low}")
        for name in ("pad", "pnp_threshold_px"):
            if not getattr(self, name) > 0:
                raise UserError(f"SingleFrameOptions.{name} = {getattr(self, name)} must be > 0")


def frame_candidates(rgb: np.ndarray, depth: np.ndarray, mask: np.ndarray, K: np.ndarray, bank: TemplateBank,
                     backbone, opts: SingleFrameOptions) -> FrameCandidates | None:
    """None when the mask is empty or too small to crop (a recorded no-estimate for that frame)."""
    timings = {}
    t0 = time.perf_counter()
    if mask.sum() < opts.min_mask_px:
        return None
    crop = crop_around_mask(rgb, depth, mask, K, backbone.crop_size, opts.pad)
    feats = backbone.extract(crop)
    timings["backbone"] = 1e3 * (time.perf_counter() - t0)
    if len(feats.uv) == 0:
        return FrameCandidates(crop.K, [], 0, timings)

    t0 = time.perf_counter()
    refs, sims = bank.bow.retrieve(feats.desc, opts.k_r)
    timings["retrieval"] = 1e3 * (time.perf_counter() - t0)
    observed = _observed(crop, feats.uv)

    candidates, t_match, t_pnp = [], 0.0, 0.0
    for ref, sim in zip(refs, sims):
        t0 = time.perf_counter()
        _, xyz_t, desc_t = bank.features(int(ref))
        pairs, _ = best_buddies(feats.desc, desc_t, opts.max_matches)
        t1 = time.perf_counter()
        uv, xyz = feats.uv[pairs[:, 0]], xyz_t[pairs[:, 1]]
        solved = solve_pnp(uv, xyz, crop.K, opts.pnp_threshold_px, opts.pnp_iterations)
        t_match += t1 - t0
        t_pnp += time.perf_counter() - t1
        if solved is None:
            continue
        T, inlier = solved
        candidates.append(Candidate(int(ref), T, uv[inlier], xyz[inlier], observed[pairs[inlier, 0]], float(sim)))
    timings["matching"] = 1e3 * t_match
    timings["pnp"] = 1e3 * t_pnp
    return FrameCandidates(crop.K, candidates, len(feats.uv), timings)


def _observed(crop: Crop, uv: np.ndarray) -> np.ndarray:
    z = depth_at(crop.depth, uv)
    pts = backproject(uv, z, crop.K)
    pts[z <= 0] = np.nan
    return pts
