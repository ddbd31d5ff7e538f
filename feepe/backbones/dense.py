"""Weight-free dense descriptors: upright SIFT on the masked image, camera-frame depth normals, colour, and
OpenCV-contrib's built-in descriptors (feepe/backbones/contrib.py: vgg, boost, beblid, teblid, daisy, latch).

Names combine parts with '+', e.g. `sift+normals`. SIFT is computed upright (angle 0) because the
templates already cover the in-plane rotations; the normal part pools the depth normals (rotated as if
the object were centred in the image) in a 4x4 grid of cells around each point; the colour part pools
chromaticity the same way. Each part is unit length and weighted, so cosine similarity averages them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from feepe.backbones import contrib
from feepe.backbones.base import PatchFeatures, grid_points, unit_rows
from feepe.crop import Crop
from feepe.depth import align_to_axis, normal_map

PARTS = ("sift", "normals", "color") + contrib.NAMES


def _cell_offsets(cell: float) -> np.ndarray:
    k = (np.arange(4) - 1.5) * cell
    gx, gy = np.meshgrid(k, k)
    return np.stack([gx.ravel(), gy.ravel()], 1)


def _pooled(values: np.ndarray, valid: np.ndarray, uv: np.ndarray, cell: int) -> np.ndarray:
    """Mean of `values` (H, W, C) over valid pixels in 4x4 cells of side `cell` around each point."""
    h, w, c = values.shape
    sums = cv2.boxFilter((values * valid[..., None]).astype(np.float32), -1, (cell, cell), normalize=False,
                         borderType=cv2.BORDER_CONSTANT)
    counts = cv2.boxFilter(valid.astype(np.float32), -1, (cell, cell), normalize=False,
                           borderType=cv2.BORDER_CONSTANT)
    centres = uv[:, None, :] + _cell_offsets(cell)[None]
    x = np.clip(np.round(centres[..., 0]).astype(int), 0, w - 1)
    y = np.clip(np.round(centres[..., 1]).astype(int), 0, h - 1)
    mean = sums[y, x] / np.maximum(counts[y, x], 1.0)[..., None]
    return mean.reshape(len(uv), 16 * c)  # 4x4 cells of c values; -1 cannot be inferred for no points


@dataclass
class DenseBackbone:
    parts: tuple[str, ...] = ("sift", "normals", "color")
    crop_size: int = 128
    stride: int = 4
    sift_size: float = 16.0
    cell: int = 4
    weights: dict = field(default_factory=lambda: {**{p: 1.0 for p in PARTS}, "color": 0.5})

    def __post_init__(self):
        self._engine = cv2.SIFT_create()
        self._contrib = {p: contrib.ContribDescriptor(p, self.sift_size) for p in self.parts if p in contrib.NAMES}

    @property
    def name(self) -> str:
        return "+".join(self.parts)

    def options(self) -> dict:
        return {"backbone": self.name, "crop_size": self.crop_size, "stride": self.stride,
                "sift_size": self.sift_size, "cell": self.cell, "weights": {p: self.weights[p] for p in self.parts}}

    def extract(self, crop: Crop) -> PatchFeatures:
        uv = grid_points(crop.mask, self.stride, self.stride / 2.0)
        blocks = []
        for part in self.parts:
            if part in self._contrib:
                gray = cv2.cvtColor(crop.rgb, cv2.COLOR_RGB2GRAY)
                blocks.append(self.weights[part] * self._contrib[part].compute(gray, uv))
            else:
                blocks.append(self.weights[part] * getattr(self, f"_{part}")(crop, uv))
        return PatchFeatures(uv, unit_rows(np.concatenate(blocks, 1)) if len(uv) else np.zeros((0, 1), np.float32))

    def _sift(self, crop: Crop, uv: np.ndarray) -> np.ndarray:
        if not len(uv):
            return np.zeros((0, 128))
        gray = cv2.cvtColor(crop.rgb, cv2.COLOR_RGB2GRAY)
        keypoints = [cv2.KeyPoint(float(x), float(y), self.sift_size, 0.0) for x, y in uv]
        kept, desc = self._engine.compute(gray, keypoints)
        if len(kept) != len(uv):
            raise RuntimeError("SIFT dropped grid keypoints; the grid must stay inside the crop")
        root = np.sqrt(desc / np.maximum(desc.sum(1, keepdims=True), 1e-12))  # RootSIFT (Hellinger)
        return unit_rows(root)

    def _normals(self, crop: Crop, uv: np.ndarray) -> np.ndarray:
        n, valid = normal_map(crop.depth, crop.K)
        centre = np.array([(crop.size - 1) / 2.0] * 2)
        n = n @ align_to_axis(crop.K, centre).T
        return unit_rows(_pooled(n, valid, uv, self.cell))

    def _color(self, crop: Crop, uv: np.ndarray) -> np.ndarray:
        rgb = crop.rgb.astype(np.float32)
        chroma = rgb / np.maximum(rgb.sum(-1, keepdims=True), 1.0)  # brightness-free, lighting varies
        return unit_rows(_pooled(chroma - 1.0 / 3.0, crop.mask, uv, self.cell))
