"""A first calibration from the robot's motion, for an RGB camera with no mask (our extension, issue 34; not in
the paper).

With no depth the robot cannot be registered to the scene's points (registration.py). A still camera watching
the robot move shows where it is all the same: between two frames the image changes where the robot came or
went, where it moved over itself and where its shadow moved, and nowhere else. Under a candidate calibration
the robot model, placed by forward kinematics, predicts per pair of frames the pixels it swept (drawn in one
frame, not in the other) and those it covered in either. Two shares are read off the coarse images: of the
swept pixels those that changed, and of the changed pixels those the robot covered; a calibration's score is
their harmonic mean (F1), averaged over the pairs. Shadows and the robot's motion over itself lower the second
share of every calibration alike. It is background subtraction turned round: the model says where the
foreground must be, the frames say where anything moved.

The search: rotations uniform on SO(3), each placed at a few distances where its moving parts' pixels overlap
the changed ones best (a cross-correlation over image shifts, cv2.matchTemplate); the best placements are
scored and refined by a (1 + lambda) evolution strategy on the score. What comes out is a start a centimetre or
a few degrees off; the outline refinement on the estimator's own segmentation does the rest.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numba
import numpy as np
from scipy.spatial.transform import Rotation

from feepe.raster import to_pixel
from feepe.registration import exposure_gain, is_new
from kernel.camera import project
from kernel.transforms import fibonacci_sphere

WIDTH_PX = 80  # the coarse images' width: a pixel spans 2-3 cm on a robot 1-2 m away, as the starts are off
CHANGE_RGB = 25.0  # colour distance (0-255, the image brought to white) between two frames that counts as a change
SHADOW_ALPHA = (0.2, 0.9)  # a shadow dims a colour to this share of its brightness
SHADOW_DISTORTION = 0.08  # and turns it by at most this (the colour's component across the lit one, relative)
CLIP_FRAMES = 32  # frames a clip keeps, the latest: a robot that never shows enough motion costs no more memory
MAX_FRAMES = 8  # frames scored, spread evenly over the clip (first and last among them)
MIN_GAP = 2  # frames paired at least this far apart among those (neighbours barely move)
MAX_PAIRS = 24  # pairs scored, spread evenly over those there are
MOVED_M = 0.01  # a surface sample that moves this far over the frames belongs to a moving part
MIN_CHANGED = 0.01  # a clip whose frames changed on less than this share of its pixels shows too little motion
VIEWS, ROLLS = 160, 16  # the rotations tried: viewing directions on a Fibonacci sphere (16 deg apart) x turns
# about the optical axis (22.5 deg); every rotation lies within about 15 deg of one, where the strategy takes
# over (2000 random rotations left a 17.7 deg hole at mini scene 7's true one)
DISTANCES_M = (0.6, 0.85, 1.2, 1.7, 2.4, 3.4)  # the moving parts' centre placed this far from the camera, then
DISTANCE_STEPS = (2 ** 0.25, 2 ** 0.125)  # at these factors nearer and farther than the best: a scale off by a
# sixth moved the placement of mini scene 7's true rotation by 10-19 cm, with these steps 3.5-4.7 cm
PLACE_POINTS = 1500  # the moving parts' samples the placement projects
UNCHANGED_WEIGHT = 0.5  # the placement's cross-correlation: an unchanged pixel under the moving parts costs this
LOCAL_STARTS = 20  # best placements refined
ES_OFFSPRING, ES_ROUNDS = 10, 60  # the evolution strategy: candidates per round, rounds at most
ES_STEP = (0.12, 0.06)  # its first steps' spread: rad about the robot's centre, m (at 1.5 m; scaled with distance)
ES_DEPTH_STEPS = 3.0  # its steps along the optical axis this many times wider: a robot's image moves about
# distance / size (3 at 1.5 m) times less when it moves along the axis than across it
ES_SHRINK, ES_MIN_RAD = 0.7, 0.005  # a round without gain shrinks the steps so; below this the search ends


@dataclass
class MotionClip:
    """The frames seen so far, coarse: their colours brought to white by the first frame's gain, and the
    robot's surface samples placed by each frame's joint states (base frame)."""
    K: np.ndarray | None = None  # the coarse grid's intrinsics
    images: list[np.ndarray] = field(default_factory=list)  # (h, w, 3) float32
    points: list[np.ndarray] = field(default_factory=list)  # (P, 3) metres
    gain: float = 1.0

    def add(self, rgb: np.ndarray, K: np.ndarray, points_base: np.ndarray) -> None:
        """The frame joins the clip; beyond CLIP_FRAMES the oldest leaves it."""
        image, K_coarse = coarse(rgb, K)
        if not self.images:
            self.K, self.gain = K_coarse, exposure_gain(rgb)
        self.images.append(image * self.gain)
        self.points.append(np.asarray(points_base, float))
        del self.images[:-CLIP_FRAMES], self.points[:-CLIP_FRAMES]

    def __len__(self) -> int:
        return len(self.images)


def coarse(rgb: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The image averaged down to WIDTH_PX columns (or kept, if narrower) and the intrinsics of that grid."""
    h, w = rgb.shape[:2]
    scale = min(1.0, WIDTH_PX / w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    image = cv2.resize(np.asarray(rgb, np.float32), size, interpolation=cv2.INTER_AREA)
    sx, sy = size[0] / w, size[1] / h
    K_coarse = np.array(K, float)
    K_coarse[0] *= sx
    K_coarse[1] *= sy
    K_coarse[0, 2] = (K[0, 2] + 0.5) * sx - 0.5  # pixel centres at integers on both grids
    K_coarse[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return image, K_coarse


class MotionFit:
    """The score of calibrations on a clip: the robot's coarse masks per frame against the changes per pair."""

    def __init__(self, clip: MotionClip):
        frames = np.unique(np.linspace(0, len(clip) - 1, min(MAX_FRAMES, len(clip))).round().astype(int))
        n = len(frames)
        pairs = [(a, b) for a in range(n) for b in range(a + MIN_GAP, n)]
        if len(pairs) > MAX_PAIRS:
            pairs = [pairs[i] for i in np.linspace(0, len(pairs) - 1, MAX_PAIRS).round().astype(int)]
        self.a = np.array([p[0] for p in pairs], int)
        self.b = np.array([p[1] for p in pairs], int)
        images = np.stack([clip.images[i] for i in frames])
        changed = np.linalg.norm(images[self.a] - images[self.b], axis=-1) > CHANGE_RGB  # (pairs, h, w)
        self.shadow = changed & shadow_like(images[self.a], images[self.b])
        self.changed = changed & ~self.shadow
        self.n_changed = self.changed.reshape(len(pairs), -1).sum(1)
        self.shape = images.shape[1:3]
        self.K = clip.K
        self.points = np.stack([clip.points[i] for i in frames])  # (frames, P, 3)
        self.moving = np.linalg.norm(self.points - self.points[:1], axis=-1).max(0) > MOVED_M

    @property
    def enough(self) -> bool:
        """Whether the frames changed enough, and the robot moved, for the motion to tell calibrations apart."""
        return (len(self.a) > 0 and self.moving.any()
                and np.count_nonzero(self.changed.any(0)) >= MIN_CHANGED * self.changed[0].size)

    def masks(self, T_cam_base: np.ndarray) -> np.ndarray:
        """(frames, h, w) bool: the robot's samples splatted on the coarse grid, gaps of a pixel closed."""
        return _drawn(self.points, np.ascontiguousarray(T_cam_base[:3, :4]), self.K, *self.shape) > 0

    def score(self, T_cam_base: np.ndarray) -> float:
        return _score(self.points, np.ascontiguousarray(T_cam_base[:3, :4]), self.K, self.a, self.b, self.changed,
                      self.shadow, self.n_changed)

    def centre(self) -> np.ndarray:
        """The robot's centre over the clip (base frame): the evolution strategy turns about it."""
        return self.points.reshape(-1, 3).mean(0)


def shadow_like(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Where one colour is the other darkened, hue and saturation kept (Horprasert et al. 1999's brightness and
    chromaticity distortion, taken from the brighter of the two): a shadow moved there, or a grey part over a
    grey floor. Such changes say nothing either way."""
    bright = np.linalg.norm(a, axis=-1) >= np.linalg.norm(b, axis=-1)
    lit = np.where(bright[..., None], a, b)
    dim = np.where(bright[..., None], b, a)
    alpha = np.sum(dim * lit, -1) / np.maximum(np.sum(lit * lit, -1), 1e-6)
    distortion = np.linalg.norm(dim - alpha[..., None] * lit, axis=-1) / np.maximum(np.linalg.norm(lit, axis=-1), 1e-6)
    return (alpha >= SHADOW_ALPHA[0]) & (alpha <= SHADOW_ALPHA[1]) & (distortion <= SHADOW_DISTORTION)


@numba.njit(cache=True, nogil=True, parallel=True)
def _drawn(points, T, K, h, w):
    """Each frame's points (frames, n, 3; base frame) placed by T (3 x 4, T_cam_base) and splatted on the grid
    of K, then closed (dilated and eroded by 3 x 3, nothing beyond the border), as cv2.morphologyEx's
    MORPH_CLOSE: the samples' gaps of a pixel filled. The frames on both cores, each on one."""
    n_frames = points.shape[0]
    dots = np.zeros((n_frames, h, w), np.uint8)
    grown = np.zeros_like(dots)
    out = np.zeros_like(dots)
    for f in numba.prange(n_frames):
        for i in range(points.shape[1]):
            x, y, z = points[f, i, 0], points[f, i, 1], points[f, i, 2]
            cz = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
            if cz <= 0.05:
                continue
            pu, pv = to_pixel(K[0, 0], K[1, 1], K[0, 2], K[1, 2], T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3],
                              T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3], cz)
            u, v = int(np.floor(pu + 0.5)), int(np.floor(pv + 0.5))
            if 0 <= u < w and 0 <= v < h:
                dots[f, v, u] = 1
        for v in range(h):
            for u in range(w):
                if dots[f, v, u]:
                    for dv in range(max(0, v - 1), min(h, v + 2)):
                        for du in range(max(0, u - 1), min(w, u + 2)):
                            grown[f, dv, du] = 1
        for v in range(h):
            for u in range(w):
                if not grown[f, v, u]:
                    continue
                keep = True
                for dv in range(max(0, v - 1), min(h, v + 2)):
                    for du in range(max(0, u - 1), min(w, u + 2)):
                        if not grown[f, dv, du]:
                            keep = False
                out[f, v, u] = keep
    return out


@numba.njit(cache=True, nogil=True, parallel=True)
def _score(points, T, K, a, b, changed, shadow, n_changed):
    """MotionFit.score's F1 per pair, averaged: of the pixels swept (drawn in one frame of the pair, not in the
    other; shadow-like changes left out) those that changed, and of the changed ones those drawn in either. The
    pairs on both cores, their F1s summed in order (the RGB-only search scores some 30,000 calibrations)."""
    h, w = changed.shape[1], changed.shape[2]
    drawn = _drawn(points, T, K, h, w)
    f1 = np.zeros(a.shape[0])
    for k in numba.prange(a.shape[0]):
        swept = 0
        seen = 0
        explained = 0
        for v in range(h):
            for u in range(w):
                da, db = drawn[a[k], v, u], drawn[b[k], v, u]
                if da != db and not shadow[k, v, u]:
                    swept += 1
                    if changed[k, v, u]:
                        seen += 1
                if (da or db) and changed[k, v, u]:
                    explained += 1
        p = seen / max(swept, 1)
        r = explained / max(n_changed[k], 1)
        if p + r > 1e-9:
            f1[k] = 2 * p * r / (p + r)
    total = 0.0
    for k in range(a.shape[0]):
        total += f1[k]
    return total / max(a.shape[0], 1)


def place(fit: MotionFit, R_cam_base: np.ndarray, weights: np.ndarray, moving: np.ndarray) -> tuple[np.ndarray | None, float]:
    """The best-scoring calibration with rotation R_cam_base, and its score: the moving parts (`moving`: their
    samples over the clip, base frame) placed at each of DISTANCES_M, then at finer steps about the best,
    each time shifted in the image to where their pixels overlap `weights` most."""
    tried = {z: _placed_at(fit, R_cam_base, weights, moving, z) for z in DISTANCES_M}
    for step in DISTANCE_STEPS:
        z = max(tried, key=lambda d: tried[d][1])
        for finer in (z / step, z * step):
            tried[finer] = _placed_at(fit, R_cam_base, weights, moving, finer)
    return max(tried.values(), key=lambda p: p[1])


def _placed_at(fit: MotionFit, R_cam_base: np.ndarray, weights: np.ndarray, moving: np.ndarray,
               z: float) -> tuple[np.ndarray | None, float]:
    """The moving parts' centre `z` from the camera, shifted in the image to where their pixels overlap
    `weights` (the changed pixels +1, the others -UNCHANGED_WEIGHT, on a canvas padded by the image's size
    with 0) most (cv2.matchTemplate); the calibration and its score, (None, -inf) when they do not fit."""
    h, w = fit.shape
    K = fit.K
    centre = moving.mean(0)
    t = z * np.linalg.solve(K, [(w - 1) / 2, (h - 1) / 2, 1.0]) - R_cam_base @ centre
    P = moving @ R_cam_base.T + t
    if np.any(P[:, 2] < 0.05):
        return None, -np.inf
    u, v = project(P, K, min_z=0.05).T
    u0, v0 = int(np.floor(u.min())), int(np.floor(v.min()))
    tw, th = int(u.max()) - u0 + 1, int(v.max()) - v0 + 1
    if tw >= weights.shape[1] or th >= weights.shape[0] or tw * th < 4:
        return None, -np.inf
    template = np.zeros((th, tw), np.uint8)
    template[(v - v0).astype(int), (u - u0).astype(int)] = 1
    template = cv2.morphologyEx(template, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)).astype(np.float32)
    _, _, _, (x, y) = cv2.minMaxLoc(cv2.matchTemplate(weights, template, cv2.TM_CCORR))
    T = np.eye(4)
    T[:3, :3] = R_cam_base
    T[:3, 3] = z * np.linalg.solve(K, [(w - 1) / 2 + x - w - u0, (h - 1) / 2 + y - h - v0, 1.0]) - R_cam_base @ centre
    return T, fit.score(T)


def refine(fit: MotionFit, T_cam_base: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """A (1 + lambda) evolution strategy on the score: turns about the robot's centre and shifts (camera frame),
    the best of ES_OFFSPRING kept when it gains, the steps shrunk when none does."""
    centre = fit.centre()
    best = fit.score(T_cam_base)
    rad, metres = ES_STEP
    for _ in range(ES_ROUNDS):
        distance = max(0.3, (T_cam_base[:3, :3] @ centre + T_cam_base[:3, 3])[2])
        spread = metres * distance / 1.5 * np.array([1.0, 1.0, ES_DEPTH_STEPS])
        trials = [_moved(T_cam_base, centre, rng.normal(0, rad, 3), rng.normal(0, spread)) for _ in range(ES_OFFSPRING)]
        scores = [fit.score(T) for T in trials]
        k = int(np.argmax(scores))
        if scores[k] > best:
            best, T_cam_base = scores[k], trials[k]
        else:
            rad, metres = rad * ES_SHRINK, metres * ES_SHRINK
            if rad < ES_MIN_RAD:
                break
    return T_cam_base, best


def _moved(T: np.ndarray, centre_base: np.ndarray, rotvec: np.ndarray, shift: np.ndarray) -> np.ndarray:
    c = T[:3, :3] @ centre_base + T[:3, 3]
    R = Rotation.from_rotvec(rotvec).as_matrix()
    out = np.eye(4)
    out[:3, :3] = R @ T[:3, :3]
    out[:3, 3] = R @ (T[:3, 3] - c) + c + shift
    return out


def rotation_grid(views: int, rolls: int) -> np.ndarray:
    """(views x rolls, 3, 3) R_cam_base: the camera's optical axis along each of `views` directions spread evenly
    over the sphere (a Fibonacci lattice), turned about it in `rolls` even steps."""
    axis = fibonacci_sphere(views)
    helper = np.where(np.abs(axis[:, 2:]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    x = np.cross(helper, axis)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    R_base_cam = np.stack([x, np.cross(axis, x), axis], 2)  # columns: the camera's x, y, z in the base frame
    turns = Rotation.from_euler("z", np.arange(rolls)[:, None] * 2 * np.pi / rolls).as_matrix()
    return np.einsum("vij,rjk->vrik", R_base_cam, turns).reshape(-1, 3, 3).transpose(0, 2, 1)


def motion_starts(fit: MotionFit, keep: int, seed: int = 0) -> list[tuple[np.ndarray, float]]:
    """Up to `keep` calibrations (T_cam_base, score), best first, from the clip's motion alone; [] when the
    clip shows too little of it."""
    if not fit.enough:
        return []
    h, w = fit.shape
    weights = np.zeros((3 * h, 3 * w), np.float32)
    weights[h:2 * h, w:2 * w] = np.where(fit.changed.any(0), 1.0, -UNCHANGED_WEIGHT)
    moving = fit.points[:, fit.moving].reshape(-1, 3)
    moving = moving[np.linspace(0, len(moving) - 1, min(PLACE_POINTS, len(moving))).astype(int)]
    placed = [place(fit, R, weights, moving) for R in rotation_grid(VIEWS, ROLLS)]
    ranked = [T for T, _ in sorted((p for p in placed if p[0] is not None), key=lambda p: -p[1])[:LOCAL_STARTS]]
    rng = np.random.default_rng(seed)
    refined = sorted((refine(fit, T, rng) for T in ranked), key=lambda r: -r[1])
    out: list[tuple[np.ndarray, float]] = []
    for T, s in refined:
        if is_new(T, [U for U, _ in out]):
            out.append((T, s))
    return out[:keep]
