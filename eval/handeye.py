"""Marker hand-eye calibration, the paper's marker baseline: ChArUco board poses from images (cv2.aruco)
and `cv2.calibrateHandEye` from N views, for a static camera watching a board bolted to the end-effector.

Eye-to-hand with OpenCV's eye-in-hand solver: hand it the base pose in the gripper frame (the inverse of
forward kinematics) with the board pose in the camera, and it returns the camera pose in the base.
"""

from __future__ import annotations

import cv2
import numpy as np

from kernel.errors import UserError
from kernel.transforms import inv_T, make_T
from syneepose.scene.marker import MarkerBoard

METHODS = {"tsai": cv2.CALIB_HAND_EYE_TSAI, "park": cv2.CALIB_HAND_EYE_PARK, "horaud": cv2.CALIB_HAND_EYE_HORAUD,
           "andreff": cv2.CALIB_HAND_EYE_ANDREFF, "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS}
MIN_CORNERS = 6


class BoardDetector:
    def __init__(self, board: MarkerBoard):
        self.board = board
        self._cv_board = board.cv_board()
        self._detector = cv2.aruco.CharucoDetector(self._cv_board)
        self._bias = self._corner_bias()

    def _corner_bias(self) -> np.ndarray:
        """The detector's constant corner offset, measured on a drawn board whose corners are known.

        OpenCV's CharucoDetector returns corners 0.5 px right and down of the pixel-centre convention
        (opencv/opencv#25539, fixed after 4.10); measuring it keeps this right on either side of the fix.
        """
        px = 40
        cols, rows = self.board.squares
        image = self._cv_board.generateImage((cols * px, rows * px), marginSize=0)
        image = cv2.GaussianBlur(cv2.copyMakeBorder(image, px, px, px, px, cv2.BORDER_CONSTANT, value=255), (0, 0), 1.0)
        corners, ids, _, _ = self._detector.detectBoard(image)
        if ids is None:
            return np.zeros(2)
        # a corner between pixels k - 1 and k sits at k - 0.5 with pixel centres at integers
        truth = self._cv_board.getChessboardCorners()[ids.ravel(), :2] / self.board.square * px + px - 0.5
        return (corners.reshape(-1, 2) - truth).mean(0)

    def T_cam_board(self, rgb: np.ndarray, K: np.ndarray) -> tuple[np.ndarray | None, int]:
        """The board pose and how many ChArUco corners it rests on; None when fewer than MIN_CORNERS."""
        gray = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
        corners, ids, _, _ = self._detector.detectBoard(gray)
        if ids is None or len(ids) < MIN_CORNERS:
            return None, 0 if ids is None else len(ids)
        obj, img = self._cv_board.matchImagePoints(corners - self._bias.astype(np.float32), ids)
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, None, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            return None, len(ids)
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, None, rvec, tvec)
        return make_T(cv2.Rodrigues(rvec)[0], tvec.ravel()), len(ids)


def calibrate(T_base_ee: list[np.ndarray], T_cam_board: list[np.ndarray], method: str = "tsai") -> np.ndarray:
    """T_cam_base from >= 3 views (each: FK pose of the end-effector, detected board pose)."""
    if method not in METHODS:
        raise UserError(f"hand-eye method {method!r} unknown; choose from {', '.join(METHODS)}")
    if len(T_base_ee) < 3:
        raise UserError(f"hand-eye calibration needs at least 3 views with the board detected, got {len(T_base_ee)}")
    T_ee_base = [inv_T(np.asarray(T)) for T in T_base_ee]
    R_cam, t_cam = cv2.calibrateHandEye([T[:3, :3] for T in T_ee_base], [T[:3, 3] for T in T_ee_base],
                                        [T[:3, :3] for T in T_cam_board], [T[:3, 3] for T in T_cam_board],
                                        method=METHODS[method])
    return inv_T(make_T(R_cam, t_cam.ravel()))
