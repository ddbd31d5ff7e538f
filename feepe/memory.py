"""The key-frame memory: a pool of past frames with their candidates, and farthest-point key frames.

A frame joins the pool only when its end-effector orientation is more than `threshold_deg` from every
pooled frame (BundleTrack's rule, as in the paper). Our silhouette refinement also admits a frame whose
end-effector moved more than `threshold_m` from every pooled frame of similar orientation: under a static
camera a translation alone is a new view too, and the lever arm a calibration's rotation rests on.
Orientations are compared through forward kinematics: with a static camera, the angle between two
camera-frame end-effector rotations equals the angle between their base-frame rotations, and the latter
carries no estimation error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from feepe.candidates import FrameCandidates
from kernel.transforms import rotation_angle


@dataclass
class MemoryEntry:
    frame: int  # order of arrival
    T_base_ee: np.ndarray  # (4, 4) from forward kinematics
    found: FrameCandidates


class MemoryPool:
    def __init__(self, threshold_deg: float = 10.0, threshold_m: float = np.inf):
        self.threshold, self.threshold_m = np.deg2rad(threshold_deg), threshold_m
        self.entries: list[MemoryEntry] = []

    def __len__(self) -> int:
        return len(self.entries)

    def _rotations(self) -> np.ndarray:
        return np.stack([e.T_base_ee[:3, :3] for e in self.entries])

    def consider(self, entry: MemoryEntry, need_candidates: bool = True) -> bool:
        """Add the frame if it is a new enough view and has any candidate (or, `need_candidates` False, a
        mask of its own to fit); True when added."""
        if need_candidates and not entry.found.candidates:
            return False
        if self.entries:
            near = rotation_angle(self._rotations(), entry.T_base_ee[:3, :3]) <= self.threshold
            positions = np.stack([e.T_base_ee[:3, 3] for e in self.entries])
            moved = np.linalg.norm(positions - entry.T_base_ee[:3, 3], axis=1)
            if (near & (moved <= self.threshold_m)).any():
                return False
        self.entries.append(entry)
        return True

    def key_frames(self, R_start: np.ndarray, k: int) -> list[MemoryEntry]:
        """Farthest-point sampling on rotation distance, seeded with the current (predicted) orientation."""
        if k <= 0 or not self.entries:
            return []
        R = self._rotations()
        nearest = rotation_angle(R, R_start)
        chosen = []
        for _ in range(min(k, len(R))):
            i = int(np.argmax(nearest))
            chosen.append(i)
            nearest = np.minimum(nearest, rotation_angle(R, R[i]))
            nearest[chosen] = -1.0
        return [self.entries[i] for i in chosen]
