"""`handeye`: marker hand-eye calibration run online over a marker segment (`render --marker`).

Every frame where the ChArUco board is found adds a view; from 3 views on, `cv2.calibrateHandEye`
(`--hand-eye tsai|park|horaud|andreff|daniilidis`) over all views so far gives `T_cam_base`, and the
end-effector pose follows from forward kinematics. Earlier frames are recorded no-estimates.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eval.handeye import METHODS, BoardDetector, calibrate
from eval.methods import option, register
from eval.methods.base import Estimate, Observation
from kernel.bop import SceneMeta
from kernel.errors import UserError
from syneepose.scene.marker import MarkerBoard


@dataclass(frozen=True)
class HandEyeFlags:
    hand_eye: str = option("tsai", "the cv2.calibrateHandEye solver", choices=tuple(METHODS))


@register("handeye")
class HandEye:
    Options = HandEyeFlags

    def __init__(self, flags: HandEyeFlags):
        self.solver = flags.hand_eye
        self._detector: BoardDetector | None = None
        self._views: list[tuple[np.ndarray, np.ndarray]] = []

    def options(self) -> dict:
        return {"hand_eye": self.solver}

    def start_scene(self, meta: SceneMeta, scene_dir: Path) -> None:
        if meta.marker is None:
            raise UserError(f"{scene_dir}: no marker board in scene_robot.json; render marker segments with "
                            "`python -m syneepose render --marker`")
        self._detector = BoardDetector(MarkerBoard.from_json(meta.marker))
        self._views = []

    def estimate(self, obs: Observation) -> Estimate:
        start = time.perf_counter()
        T_cam_board, n_corners = self._detector.T_cam_board(obs.rgb, obs.K)
        if T_cam_board is not None:
            self._views.append((obs.T_base_ee, T_cam_board))
        T_cam_base = None
        if len(self._views) >= 3:
            T_cam_base = calibrate([v[0] for v in self._views], [v[1] for v in self._views], self.solver)
        return Estimate(T_cam_ee=None if T_cam_base is None else T_cam_base @ obs.T_base_ee,
                        score=float(n_corners), time_s=time.perf_counter() - start, T_cam_base=T_cam_base,
                        extra={"views": len(self._views)})
