"""OpenCV-contrib's local descriptors that ship inside the library, computed on the dense grid (issue 13,
item 4): learned ones whose weights are compiled in (VGG: Simonyan et al., TPAMI 2014; BoostDesc: Trzcinski
et al., CVPR 2013 / TPAMI 2015; BEBLID / TEBLID: Suarez et al., Pattern Recognition Letters 2020 / 2021)
and two hand-made ones (DAISY: Tola et al., TPAMI 2010; LATCH: Levi and Hassner, WACV 2016).

Each is computed upright at the grid points with the keypoint size of the SIFT part; binary descriptors
become +-1 vectors, so the cosine similarity of two of them is 1 - 2 x their normalised Hamming distance.
The crop is padded with its black background first, because these extractors silently drop keypoints
near the image border and the grid must keep every point.
"""

from __future__ import annotations

import cv2
import numpy as np

from feepe.backbones.base import unit_rows

SIFT_SCALE = 6.75  # the extractors' scale factor for SIFT-sized keypoints (OpenCV's documentation)
PAD_PX = 48  # LATCH's 48 px window is the widest footprint among these


def _engines() -> dict:
    x = cv2.xfeatures2d
    return {
        "vgg": lambda: x.VGG_create(scale_factor=SIFT_SCALE),
        "boost": lambda: x.BoostDesc_create(scale_factor=SIFT_SCALE),
        "beblid": lambda: x.BEBLID_create(SIFT_SCALE),
        "teblid": lambda: x.TEBLID_create(SIFT_SCALE),
        "daisy": lambda: x.DAISY_create(),
        "latch": lambda: x.LATCH_create(32, False),
    }


NAMES = ("vgg", "boost", "beblid", "teblid", "daisy", "latch")


class ContribDescriptor:
    def __init__(self, name: str, size: float):
        self.name, self.size = name, size
        self._engine = _engines()[name]()

    def compute(self, gray: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Unit-length descriptors, one row per grid point, in the order of `uv`."""
        if not len(uv):
            return np.zeros((0, 1), np.float32)
        padded = cv2.copyMakeBorder(gray, PAD_PX, PAD_PX, PAD_PX, PAD_PX, cv2.BORDER_CONSTANT, value=0)
        keypoints = [cv2.KeyPoint(float(x) + PAD_PX, float(y) + PAD_PX, self.size, 0.0, 0, 0, i)
                     for i, (x, y) in enumerate(uv)]
        kept, desc = self._engine.compute(padded, keypoints)
        if desc is None or len(kept) != len(uv):
            raise RuntimeError(f"{self.name} dropped grid keypoints; PAD_PX must cover its footprint")
        order = np.argsort([k.class_id for k in kept])
        desc = desc[order]
        if desc.dtype == np.uint8:  # binary: bits to +-1
            desc = 2.0 * np.unpackbits(desc, axis=1).astype(np.float32) - 1.0
        return unit_rows(desc.astype(np.float32))
