"""A ChArUco board bolted to the end-effector, as a marker hand-eye set-up has it (pure numpy + cv2).

Board frame (OpenCV's): origin at the pattern's top-left corner, x along the `squares[0]` columns, y along
the rows, z into the board; the printed face looks along -z. The board stands beside the gripper like a
flag: its x axis along the tool axis (ee z), its face turned outwards, `clearance` beyond the widest part
of the end-effector. The turn about the tool axis is chosen per segment so the face looks at the camera
as well as it can over all frames; nothing random is drawn, so a segment's trajectory, camera and lights
are the same with and without the board (the marker-free twin is a plain render of the same scene).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from kernel.errors import UserError
from kernel.transforms import make_T
from syneepose.preset import Marker, Preset


@dataclass
class MarkerBoard:
    dictionary: str = "DICT_4X4_50"  # coarse bits: still decodable when a marker spans ~15 px
    squares: tuple[int, int] = (4, 5)
    square: float = 0.05  # metres: a 0.2 x 0.25 m board, about A4
    marker: float = 0.037
    margin: float = 0.01  # white border around the pattern
    T_ee_board: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        self.squares = tuple(int(n) for n in self.squares)  # YAML and JSON give lists
        if not hasattr(cv2.aruco, self.dictionary):
            raise UserError(f"marker dictionary {self.dictionary!r} unknown; e.g. DICT_5X5_100, DICT_6X6_250")
        if not 0 < self.marker < self.square:
            raise UserError(f"marker side {self.marker} must be positive and smaller than the square {self.square}")

    @property
    def size(self) -> tuple[float, float]:
        return self.squares[0] * self.square, self.squares[1] * self.square

    def corners(self) -> np.ndarray:
        """Every square corner of the pattern in the board frame, (n, 3) metres: what must be seen."""
        x = np.arange(self.squares[0] + 1) * self.square
        y = np.arange(self.squares[1] + 1) * self.square
        return np.stack(np.meshgrid(x, y, [0.0]), -1).reshape(-1, 3)

    def cv_board(self):
        vocabulary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square, self.marker, vocabulary)

    def image(self, px_per_m: float = 4000.0) -> np.ndarray:
        """The printed face including its white margin, (rows, cols) uint8, top-left = board origin - margin."""
        w, h = self.size
        margin_px = int(round(self.margin * px_per_m))
        size = (int(round(w * px_per_m)) + 2 * margin_px, int(round(h * px_per_m)) + 2 * margin_px)
        return self.cv_board().generateImage(size, marginSize=margin_px)

    def to_json(self) -> dict:
        return {"dictionary": self.dictionary, "squares": list(self.squares), "square": self.square,
                "marker": self.marker, "margin": self.margin, "T_ee_board": np.asarray(self.T_ee_board).tolist()}

    @classmethod
    def from_json(cls, d: dict) -> "MarkerBoard":
        return cls(d["dictionary"], d["squares"], d["square"], d["marker"], d["margin"],
                   np.array(d["T_ee_board"], dtype=float))


def board_from_preset(preset: Preset) -> tuple[MarkerBoard, dict]:
    """The preset's `marker:` section (defaults otherwise): the board, and how it is mounted (clearance,
    height) as keyword arguments of `board_pose`."""
    m = preset.marker or Marker()
    mount = {k: v for k, v in (("clearance", m.clearance), ("height", m.height)) if v is not None}
    return MarkerBoard(m.dictionary, m.squares, m.square, m.marker, m.margin), mount


def board_pose(board: MarkerBoard, yaw: float, radius: float, clearance: float, height: float) -> np.ndarray:
    """T_ee_board for a board whose face looks along (cos yaw, sin yaw, 0) of the end-effector frame."""
    n = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    z = np.array([0.0, 0.0, 1.0])
    R = np.stack([z, np.cross(-n, z), -n], 1)
    w, h = board.size
    centre = (radius + clearance) * n + height * z
    return make_T(R, centre - R @ np.array([w / 2, h / 2, 0.0]))


def facing(T_cam_board: np.ndarray, board: MarkerBoard) -> np.ndarray:
    """Cosine between each board's face normal and the direction from its centre to the camera, (n,)."""
    w, h = board.size
    centre = T_cam_board[:, :3, :3] @ np.array([w / 2, h / 2, 0.0]) + T_cam_board[:, :3, 3]
    face = -T_cam_board[:, :3, 2]
    return np.sum(face * -centre, 1) / np.linalg.norm(centre, axis=1)


def mount_facing_camera(board: MarkerBoard, T_cam_ee: np.ndarray, radius: float, clearance: float = 0.01,
                        height: float = 0.06, steps: int = 72) -> MarkerBoard:
    """The board turned about the tool axis to maximise its worst-frame facing of the camera.

    T_cam_ee: (n_frames, 4, 4). Facing = cosine between the face normal and the direction to the camera.
    """
    best, best_score = None, -np.inf
    for yaw in np.linspace(0.0, 2 * np.pi, steps, endpoint=False):
        score = np.min(facing(T_cam_ee @ board_pose(board, yaw, radius, clearance, height), board))
        if score > best_score:
            best, best_score = yaw, score
    return MarkerBoard(board.dictionary, board.squares, board.square, board.marker, board.margin,
                       board_pose(board, best, radius, clearance, height))
