"""Masks as a segmenter gives them (issue 13, item 3): the data set's visible masks are exact, a user's come
from a SAM-like model. `--mask-noise sam` hands every method a perturbed mask instead: the boundary moved in
and out by a smooth random field of 1-4 px amplitude (parts of the outline eroded, parts dilated, thin parts
lost), up to two small false blobs near the object and up to two holes inside it. Each frame's perturbation
is drawn from (seed, scene_id, im_id), so every method and every rerun sees the same masks.

This is our own model of segmentation error, not a measured one: it is not SAM's error distribution.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from kernel.errors import UserError


@dataclass(frozen=True)
class MaskNoise:
    boundary_px: tuple[float, float] = (1.0, 4.0)  # per-frame amplitude of the boundary's shift, drawn uniformly
    wavelength_px: float = 24.0  # spacing of the shift field's random knots along the image
    max_blobs: int = 2  # false blobs within `blob_reach_px` of the mask
    max_holes: int = 2
    blob_area: tuple[float, float] = (0.005, 0.02)  # each blob or hole, as a fraction of the mask's area
    blob_reach_px: float = 20.0
    seed: int = 0

    def describe(self) -> dict:
        return asdict(self)


PRESETS = {"sam": MaskNoise}


def mask_noise(name: str, seed: int = 0) -> MaskNoise | None:
    """The named perturbation ("none" = exact masks)."""
    if seed < 0:
        raise UserError(f"--mask-seed {seed} must be >= 0")
    if name == "none":
        return None
    if name not in PRESETS:
        raise UserError(f"--mask-noise {name!r} unknown; choose none or {', '.join(PRESETS)}")
    return PRESETS[name](seed=seed)


def frame_rng(noise: MaskNoise, scene_id: int, im_id: int) -> np.random.Generator:
    return np.random.default_rng([noise.seed, scene_id, im_id])


def perturb(mask: np.ndarray, noise: MaskNoise, rng: np.random.Generator) -> np.ndarray:
    """A perturbed copy of a boolean mask; an empty mask stays empty (a segmenter that saw nothing)."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return mask.copy()
    h, w = mask.shape
    m = mask.astype(np.uint8)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    signed = np.where(mask, inside - 0.5, 0.5 - outside)  # > 0 inside, zero level on the boundary
    out = signed + _shift_field((h, w), noise, rng) > 0
    area = float(mask.sum())
    for _ in range(rng.integers(0, noise.max_blobs + 1)):
        near = np.argwhere((outside > 0) & (outside <= noise.blob_reach_px))
        if len(near):
            out |= _ellipse((h, w), near[rng.integers(len(near))], area * rng.uniform(*noise.blob_area), rng)
    for _ in range(rng.integers(0, noise.max_holes + 1)):
        deep = np.argwhere(inside >= 2)
        if len(deep):
            out &= ~_ellipse((h, w), deep[rng.integers(len(deep))], area * rng.uniform(*noise.blob_area), rng)
    return out


def _shift_field(shape: tuple[int, int], noise: MaskNoise, rng: np.random.Generator) -> np.ndarray:
    """Smooth field in [-a, a] px (a drawn per frame): > 0 dilates the boundary there, < 0 erodes it."""
    h, w = shape
    knots = rng.uniform(-1.0, 1.0, (int(np.ceil(h / noise.wavelength_px)) + 2,
                                     int(np.ceil(w / noise.wavelength_px)) + 2))
    field = cv2.resize(knots, (w, h), interpolation=cv2.INTER_CUBIC)
    field /= max(float(np.abs(field).max()), 1e-9)
    return rng.uniform(*noise.boundary_px) * field


def _ellipse(shape: tuple[int, int], centre_vu: np.ndarray, area_px: float, rng: np.random.Generator) -> np.ndarray:
    axes_ratio = rng.uniform(0.4, 1.0)
    a = max(1.0, np.sqrt(area_px / (np.pi * axes_ratio)))
    out = np.zeros(shape, np.uint8)
    cv2.ellipse(out, (int(centre_vu[1]), int(centre_vu[0])), (int(round(a)), max(1, int(round(a * axes_ratio)))),
                float(rng.uniform(0, 180)), 0, 360, 1, -1)
    return out > 0

