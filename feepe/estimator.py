"""FEEPE online: fed frame by frame, returns the end-effector pose and the camera-to-base calibration.

Variants (the paper's ablation): A = PnP only (best candidate by inliers); B = + optimisation over the
current frame's candidates; C = + key frames from the memory pool; D = + symmetry disambiguation (full).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from feepe.backbones import get_backbone
from feepe.candidates import FrameCandidates, SingleFrameOptions, frame_candidates
from feepe.memory import MemoryEntry, MemoryPool
from feepe.onboarding import TemplateBank, onboard
from feepe.optimize import OptimizeOptions, optimize, reprojection_px, stack
from feepe.symmetry import consensus
from syneepose.errors import UserError
from syneepose.transforms import inv_T

VARIANTS = ("A", "B", "C", "D")


@dataclass
class FeepeOptions:
    variant: str = "D"
    k_f: int = 8
    memory_threshold_deg: float = 10.0
    symmetry_tolerance_deg: float = 20.0
    single: SingleFrameOptions = field(default_factory=SingleFrameOptions)
    optimize: OptimizeOptions = field(default_factory=OptimizeOptions)

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise UserError(f"FEEPE variant {self.variant!r} unknown; choose one of {', '.join(VARIANTS)}")


@dataclass
class FrameResult:
    T_cam_ee: np.ndarray | None  # None: no estimate for this frame
    T_cam_base: np.ndarray | None
    score: float  # current-frame matches consistent with the final pose
    n_candidates: int
    n_key_frames: int
    timings: dict  # ms per stage and "total"


class Estimator:
    def __init__(self, bank: TemplateBank, backbone, options: FeepeOptions | None = None):
        self.bank, self.backbone = bank, backbone
        self.opts = options or FeepeOptions()
        self.reset()

    @classmethod
    def from_templates(cls, folder: Path, backbone: str = "sift+normals", options: FeepeOptions | None = None,
                       cache_dir: Path | None = None, **backbone_kwargs) -> "Estimator":
        net = get_backbone(backbone, **backbone_kwargs)
        opts = options or FeepeOptions()
        return cls(onboard(folder, net, opts.single.pad, cache_dir=cache_dir), net, opts)

    def options(self) -> dict:
        return {**asdict(self.opts), "backbone": self.backbone.options(), "n_templates": len(self.bank)}

    def reset(self) -> None:
        """Start a new sequence (a new camera placement): the memory and the last calibration go."""
        self.pool = MemoryPool(self.opts.memory_threshold_deg)
        self.T_cam_base: np.ndarray | None = None
        self.frame = 0

    def step(self, rgb: np.ndarray, depth: np.ndarray, mask: np.ndarray, K: np.ndarray,
             T_base_ee: np.ndarray) -> FrameResult:
        _check_inputs(rgb, depth, mask, K, T_base_ee)
        t_start = time.perf_counter()
        found = frame_candidates(rgb, depth, np.asarray(mask, bool), K, self.bank, self.backbone, self.opts.single)
        if found is None:
            found = FrameCandidates(np.eye(3), [], 0, {})
        timings = dict(found.timings)
        t0 = time.perf_counter()
        T_cam_base, score, n_keys = self._estimate(found, T_base_ee)
        timings["optimisation"] = 1e3 * (time.perf_counter() - t0)
        self.pool.consider(MemoryEntry(self.frame, T_base_ee, found))
        self.frame += 1
        if T_cam_base is not None:
            self.T_cam_base = T_cam_base
        timings["total"] = 1e3 * (time.perf_counter() - t_start)
        T_cam_ee = None if T_cam_base is None else T_cam_base @ T_base_ee
        return FrameResult(T_cam_ee, T_cam_base, score, len(found.candidates), n_keys, timings)

    def _estimate(self, found: FrameCandidates, T_base_ee: np.ndarray):
        opts, cands = self.opts, found.candidates
        best = max(cands, key=lambda c: c.n_inliers) if cands else None
        if opts.variant == "A":
            if best is None:
                return None, 0.0, 0
            return best.T_cam_ee @ inv_T(T_base_ee), float(best.n_inliers), 0
        frames = [(T_base_ee, found.K, cands)]
        if opts.variant in ("C", "D"):
            keys = self.pool.key_frames(T_base_ee[:3, :3], opts.k_f)
            frames += [(e.T_base_ee, e.found.K, e.found.candidates) for e in keys]
        if not any(f[2] for f in frames):
            return None, 0.0, 0
        if opts.variant == "D":
            keep, T_init = consensus([(T, c) for T, _, c in frames], opts.symmetry_tolerance_deg)
            frames = [(T, Kc, [c for c, k in zip(cs, ks) if k]) for (T, Kc, cs), ks in zip(frames, keep)]
        elif opts.variant == "C" and self.T_cam_base is not None:
            T_init = self.T_cam_base
        else:
            T_init = _init_from(frames)
        T, _ = optimize(T_init, stack(frames), opts.optimize)
        score = float(np.sum(reprojection_px(T, stack(frames[:1])) <= opts.single.pnp_threshold_px))
        return T, score, len(frames) - 1


def _init_from(frames) -> np.ndarray:
    """The calibration implied by the candidate with the most inliers among the frames."""
    T_base_ee, _, c = max(((T, K, c) for T, K, cs in frames for c in cs), key=lambda f: f[2].n_inliers)
    return c.T_cam_ee @ inv_T(T_base_ee)


def _check_inputs(rgb, depth, mask, K, T_base_ee) -> None:
    rgb, depth, mask = np.asarray(rgb), np.asarray(depth), np.asarray(mask)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise UserError(f"rgb must be (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
    if depth.shape != rgb.shape[:2] or mask.shape != rgb.shape[:2]:
        raise UserError(f"image sizes differ: rgb {rgb.shape[:2]}, depth {depth.shape}, mask {mask.shape}; "
                        "pass the depth and mask registered to the RGB image")
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise UserError(f"K must be a 3x3 intrinsics matrix with positive focal lengths, got {K.tolist()}")
    h, w = rgb.shape[:2]
    if not (-0.5 * w <= K[0, 2] <= 1.5 * w and -0.5 * h <= K[1, 2] <= 1.5 * h):
        raise UserError(f"K's principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) does not fit a {w}x{h} image; "
                        "is K for another resolution?")
    if np.shape(T_base_ee) != (4, 4):
        raise UserError(f"T_base_ee must be 4x4, got {np.shape(T_base_ee)}")
