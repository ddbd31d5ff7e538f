"""A first calibration with no mask (our extension, issue 34; not in the paper): the whole robot, placed by
forward kinematics of the frame's joint positions, found in the frame's depth.

The depth shows the robot among the floor, walls and objects. The large planes are set aside (RANSAC), the
robot's surface samples are found among the remaining points by point-pair-feature voting (Drost et al.
2010, feepe/ppf.py; the robot stands still in its base frame for this one frame, so it is one rigid
object), and each of the best pose clusters is refined by point-to-plane ICP. A robot seen close covers few of
those voxels (a UR10e's wrist at 0.6 m: 54 of 5,807 scene points, behind walls whose stereo depth strays by
tens of centimetres); once the whole scene has been searched in vain, the nearest of its connected parts are
searched again on their own at half the voxel, as Birdal and Ilic (3DV 2015) vote within scene segments. The
hypotheses are then judged
on the depth image itself: a calibration under which the model's rendered depth agrees with the sensor's
explains those pixels, one under which the sensor sees far behind the model's surface is contradicted
there (free space seen through a robot that would stand in the way). Depth alone can be fooled where a wall or
the floor lies where a wrong pose puts the robot's links; the image's colour is not: along the true outline the
colour changes across it (robot against background), along a wrong one it mostly does not (both sides wall).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from feepe.depth import normal_map
from feepe.icp import SurfaceModel, icp_into_points
from feepe.ppf import PpfDetector, PpfOptions, voxel_sample
from feepe.silhouette import outline_pixels
from kernel.camera import point_map
from kernel.transforms import rotation_angle

PPF = PpfOptions(sampling=0.04, scene_step=1, max_references=1000, hypotheses=24)  # robot-sized: 4-6 cm voxels on
# a 1-1.5 m robot. Every scene point a reference up to 1000, and 24 clusters refined: where only a UR10e's upper
# links are in view they are a tenth of the points, and the true pose was not among every third point's 8 best
# (seed-7 stereo scene 14). The clusters' ICP was cheap beside the voting while the votes were clustered in a
# Python loop (0.7-2.3 s a frame on 12 stereo segments, 6.7 s with 3920 scene points); since that loop went
# (c1c4a28) it is the larger part: 0.47 s a call against 0.32 s for voting and clustering (cProfile, two seed-29
# stereo segments)
NEAR_PPF = PpfOptions(sampling=0.02, scene_step=1, max_references=1000, hypotheses=4)  # the near pass: half the
# voxel, each part's 4 best clusters. At the first frames of 52 stereo segments (nine renders) the whole-scene
# search held no hypothesis within 3 cm and 3 deg of the truth on 11 (4 with the arm out of view, 4 on seed 29's
# path-traced IR that later frames find); this pass holds one for 2 (seed-53 scene 13, seed-29 splatted scene 11).
# It costs 0.1-3.5 s a frame more than the whole scene's 0.3-1.5 s (18 first frames of three renders, in-process,
# alone), hence only once the whole scene has failed
NEAR_PARTS = 3  # the connected parts searched again, nearest first (median depth): a camera watching a robot
# mostly sees it in front of its background
NEAR_PART_POINTS = 20  # a part of fewer scene points is noise
PART_LINK_STEPS = 1.5  # scene points closer than this many voxels are one part
PLANE_TOL_M = 0.015  # scene points this close to a large plane belong to it, or within PLANE_TOL_SIGMAS
PLANE_TOL_SIGMAS = 3.0  # of a stereo camera's noise at their depth: sigma(z) = 2 mm + 0.0036 z^2 (Intel's D435
# RMS model, as feepe.estimator's depth_sigma_*): 1.5 cm holds exact depth's floor, not a stereo floor at 3 m
PLANE_SHARE = 0.08  # a plane holding this share of the scene's points is background
MAX_PLANES = 4  # floor and walls
RANSAC_TRIALS = 200
ICP_GATES_M = (0.1, 0.01)  # ICP's association gate shrinks from 10 cm to 1 cm over its rounds
ICP_ROUNDS = 8
SAME_DEG, SAME_M = 2.0, 0.02  # calibration hypotheses closer than this in rotation and translation are one
SEEN_THROUGH_WEIGHT = 2.0  # a pixel that sees through the model costs two that agree with it
SEEN_THROUGH_M = 0.03  # and sees at least this far behind the model's surface, past the agreement's tolerance: a
# stereo camera's depth on thin parts spreads a few centimetres behind them (D435 model, mini-stereo scene 0 at
# the true calibration: 10 % of the robot's pixels 2.4 cm or more behind, 2 % beyond 5 cm); free space is farther
SEEN_THROUGH_INSET_PX = 2  # seen-through pixels count this far inside the model's outline (on the grid it is
# drawn on): a hypothesis 2 cm off the true one (seed-11 stereo scene 10, a UR5e 1.5 m away) sees past its thin
# links' edges on 254 of its 1054 pixels, 108 of them this far in, against 15 of 68 at the truth; a robot standing
# in free space is seen through in its interior
CONTRAST_OFFSET_PX = 3  # colours compared this far inside and outside the outline: past a pixel or two of pose
# error and the image's blur
CONTRAST_RGB = 15.0  # RGB distance (0-255) that tells the two sides apart in a well-exposed image. At the true
# calibration 96-100 % of the outline changes colour by more once the image is brought to white (exposure_gain;
# 30 development segments: seed-0 exact and stereo, seed-7 stereo, frame 1), at the registration's wrong
# hypotheses mostly under 80 % (5 of 115 above), on a wall or floor 0-20 %
WHITE_PERCENTILE = 99  # an image's white level: its brightest pixels' channel maximum at this percentile
MAX_GAIN = 8.0  # a dark image's colour differences count as if exposed up to this many times brighter
CONTRAST_JUDGED = 0.5  # the share of an outline that outline_contrast divides by at least: where both sides are
# within CONTRAST_RGB of black (after the gain) or of saturated white, colour cannot tell robot from background,
# and such pixels are not judged, but a pose whose outline is mostly so is not borne out by the few left. Held-out
# seed 109 scene 2 (white level 25, so the gain is capped at 8; a black Robotiq 2F-140 against a black shadow): at
# the true calibration the colour changed across 64-70 % of the outline, 95 % of the 71 % not black on black;
# hard-case exit scene 13 (an overexposed wall, a UR10e's lit side saturated against it): 61-81 % over frames 4-15


def plane_tolerance(z: np.ndarray) -> np.ndarray:
    return np.maximum(PLANE_TOL_M, PLANE_TOL_SIGMAS * (0.002 + 0.0036 * z**2))


def background_planes(points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Which points lie on one of the scene's large planes (up to MAX_PLANES, each holding PLANE_SHARE)."""
    on_plane = np.zeros(len(points), bool)
    for _ in range(MAX_PLANES):
        left = np.flatnonzero(~on_plane)
        if len(left) < 3 or len(left) < PLANE_SHARE * len(points):
            break
        trios = points[left[rng.integers(0, len(left), (RANSAC_TRIALS, 3))]]
        normals = np.cross(trios[:, 1] - trios[:, 0], trios[:, 2] - trios[:, 0])
        length = np.linalg.norm(normals, axis=1)
        ok = length > 1e-9
        normals, trios = normals[ok] / length[ok, None], trios[ok]
        distance = np.abs(np.einsum("tj,pj->tp", normals, points[left]) - np.sum(normals * trios[:, 0], 1)[:, None])
        close = distance < plane_tolerance(points[left, 2])
        counts = close.sum(1)
        if not len(counts) or counts.max() < PLANE_SHARE * len(points):
            break
        on_plane[left[close[np.argmax(counts)]]] = True
    return on_plane


def depth_cloud(depth: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel's point and camera-facing normal where the depth has both (camera frame): what the whole
    scene's search and the near pass sample, each at its own voxel."""
    normals, valid = normal_map(depth, K)
    return point_map(depth, K)[valid], normals[valid]


def scene_points(cloud: tuple[np.ndarray, np.ndarray], voxel_m: float, rng: np.random.Generator):
    """The depth_cloud's points and normals, one per voxel, without the large planes."""
    points, normals = voxel_sample(*cloud, voxel_m)
    keep = ~background_planes(points, rng)
    return points[keep], normals[keep]


def parts(points: np.ndarray, link_m: float) -> np.ndarray:
    """Each point's connected part: points closer than link_m are joined."""
    pairs = cKDTree(points).query_pairs(link_m, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points),) * 2)
    return connected_components(graph, directed=False)[1]


def near_hypotheses(model: SurfaceModel, cloud: tuple[np.ndarray, np.ndarray], points: np.ndarray,
                    step: float) -> list[np.ndarray]:
    """Unrefined T_cam_base hypotheses from the NEAR_PARTS nearest parts of the scene `points` (the depth
    `cloud` sampled at `step`), each part sampled again at NEAR_PPF's finer voxel and searched on its own."""
    label = parts(points, PART_LINK_STEPS * step)
    big = np.flatnonzero(np.bincount(label) >= NEAR_PART_POINTS)
    nearest = big[np.argsort([np.median(points[label == i, 2]) for i in big])][:NEAR_PARTS]
    fine, fine_normals = voxel_sample(*cloud, NEAR_PPF.sampling / PPF.sampling * step)
    distance, index = cKDTree(points).query(fine, distance_upper_bound=step)
    fine_label = np.where(np.isfinite(distance), label[np.minimum(index, len(points) - 1)], -1)
    chosen = [c for c in (fine_label == i for i in nearest) if c.sum() >= NEAR_PART_POINTS]
    if not chosen:
        return []
    detector = PpfDetector(model, NEAR_PPF, reach=max(np.linalg.norm(np.ptp(fine[c], axis=0)) for c in chosen))
    return [T for c in chosen for T in detector.hypotheses(fine[c], fine_normals[c])]


class SceneSearch:
    """One frame's depth made ready for the robot's search once: the robot's PPF model, the depth's points and the
    scene's points beside its large planes, from which the whole scene and its nearest parts are searched (the
    estimator's first frame searches the nearest parts only once the whole scene has failed)."""

    def __init__(self, model: SurfaceModel, depth: np.ndarray, K: np.ndarray, seed: int = 0):
        self.model, self.detector = model, PpfDetector(model, PPF)
        self.cloud = depth_cloud(depth, K)
        self.points, self.normals = scene_points(self.cloud, self.detector.step, np.random.default_rng(seed))

    def hypotheses(self, near: bool = False, whole: bool = True) -> list[np.ndarray]:
        """T_cam_base hypotheses, strongest vote first (`whole`: the whole scene's; then, with `near`, those of its
        nearest parts), each refined by ICP on the scene's points; [] when the depth holds too little."""
        if len(self.points) < 10:
            return []
        starts = self.detector.hypotheses(self.points, self.normals) if whole else []
        if near:
            starts += near_hypotheses(self.model, self.cloud, self.points, self.detector.step)
        out = []
        for T in starts:
            T = icp_into_points(T, self.points, self.model, np.linspace(*ICP_GATES_M, ICP_ROUNDS), PLANE_TOL_M / 3)
            if is_new(T, out):
                out.append(T)
        return out


def is_new(T: np.ndarray, known: list[np.ndarray]) -> bool:
    """Whether the calibration T differs from each of `known` by more than SAME_DEG or SAME_M: of several
    near-equal hypotheses one is kept."""
    return all(rotation_angle(T[:3, :3], U[:3, :3]) > np.deg2rad(SAME_DEG)
               or np.linalg.norm(T[:3, 3] - U[:3, 3]) > SAME_M for U in known)


@dataclass
class DepthFit:
    """How a calibration's rendered robot depth meets the sensor's, in pixels (on the strided grid)."""
    agree: int  # within the sensor's noise of the model's surface
    seen_through: int  # the sensor sees well behind the model's surface, SEEN_THROUGH_INSET_PX inside its outline:
    # the model cannot stand there
    drawn: int  # model pixels where the sensor has depth
    front: np.ndarray = field(repr=False)  # (H, W) bool: the model's pixels where the sensor sees nearer than its
    # surface: something (or a stereo error) hides it there (`hidden`); the colour test leaves them out

    @property
    def in_front(self) -> int:
        return int(np.count_nonzero(self.front))

    def score(self, contrast: float = 1.0) -> float:
        """`contrast`: the pose's outline_contrast; its agreeing pixels count as far as the image's colour
        bears the outline out (a wall's depth can agree with a pose lying on it, its colour does not)."""
        return contrast * self.agree - SEEN_THROUGH_WEIGHT * self.seen_through


def depth_tolerance(rendered: np.ndarray, noise_m: float = 0.01, noise_z2: float = 0.005) -> np.ndarray:
    """Within noise_m + noise_z2 z^2 (1.5 cm at 1 m) of the model's depth the sensor agrees with it: a stereo
    camera's noise and a few millimetres of calibration error."""
    return noise_m + noise_z2 * rendered**2


def depth_fit(rendered: np.ndarray, depth: np.ndarray, noise_m: float = 0.01,
                    noise_z2: float = 0.005) -> DepthFit:
    """rendered: the model's depth (m, 0 off it) on the grid of `depth`."""
    drawn = (rendered > 0) & (depth > 0)
    tolerance = depth_tolerance(rendered, noise_m, noise_z2)
    inset = np.ones((2 * SEEN_THROUGH_INSET_PX + 1,) * 2, np.uint8)
    inside = cv2.erode((rendered > 0).astype(np.uint8), inset, borderValue=1).astype(bool)
    return DepthFit(int(np.count_nonzero(drawn & (np.abs(depth - rendered) < tolerance))),
                    int(np.count_nonzero(drawn & inside & (depth > rendered + tolerance + SEEN_THROUGH_M))),
                    int(np.count_nonzero(drawn)), hidden(rendered, depth, noise_m, noise_z2))


def hidden(rendered: np.ndarray, depth: np.ndarray, noise_m: float = 0.01, noise_z2: float = 0.005) -> np.ndarray:
    """The model's pixels (`rendered`: its depth, m, 0 off it) where the sensor sees in front of its surface by
    more than `depth_fit`'s tolerance: something nearer hides the robot there (`DepthFit.front`)."""
    return (rendered > 0) & (depth > 0) & (depth <= rendered - depth_tolerance(rendered, noise_m, noise_z2))


def exposure_gain(rgb: np.ndarray) -> float:
    """The gain that brings the image's white level to 255, as a camera's auto-exposure would (at least 1, at
    most MAX_GAIN). A dark scene's colours differ by a fraction of a bright one's: in `mini` scene 15 (white level
    66, a black arm in shadow) the true calibration's outline changed colour by CONTRAST_RGB along 62 % of it,
    98 % once brought to white; images already reaching white are left as they are."""
    white = np.percentile(np.asarray(rgb).max(axis=-1), WHITE_PERCENTILE)
    return float(np.clip(255.0 / max(white, 1.0), 1.0, MAX_GAIN))


def outline_contrast(drawn: np.ndarray, rgb: np.ndarray, unseen: np.ndarray | None = None) -> float:
    """The share of the outline of `drawn` (a model's pixels in the image, bool) along which the image's colour
    CONTRAST_OFFSET_PX inside differs from the colour as far outside by more than CONTRAST_RGB, among the
    outline's pixels that are not black or white on both sides (but at least CONTRAST_JUDGED of the outline); the
    image's border is no outline, nor are the pixels `unseen` (`hidden` by something nearer: a hand reaching into
    a floor, an object before the gripper). 0 when nothing is drawn."""
    return contrast_along(drawn, contrast_image(rgb), unseen)


def contrast_image(rgb: np.ndarray) -> np.ndarray:
    """The colours outline_contrast compares: the image blurred over a pixel and brought to white
    (exposure_gain). Made once for a frame whose many hypotheses' outlines are judged (`contrast_along`)."""
    return cv2.GaussianBlur(np.asarray(rgb, np.float32), (0, 0), 1.0) * exposure_gain(rgb)


def contrast_along(drawn: np.ndarray, image: np.ndarray, unseen: np.ndarray | None = None) -> float:
    """outline_contrast on the frame's `contrast_image`."""
    mask = np.asarray(drawn, np.uint8)
    v, u = np.nonzero(outline_pixels(mask))
    if len(u) == 0:
        return 0.0
    smooth = cv2.GaussianBlur(mask.astype(np.float32), (0, 0), 2.0)
    inward = np.stack([cv2.Sobel(smooth, cv2.CV_32F, 1, 0)[v, u], cv2.Sobel(smooth, cv2.CV_32F, 0, 1)[v, u]], 1)
    inward /= np.linalg.norm(inward, axis=1, keepdims=True) + 1e-9
    pixels, step = np.stack([u, v], 1), CONTRAST_OFFSET_PX * inward
    inner, outer = np.round(pixels + step).astype(int), np.round(pixels - step).astype(int)
    size = mask.shape[::-1]
    ok = np.all((inner >= 0) & (inner < size) & (outer >= 0) & (outer < size), axis=1)
    if unseen is not None:
        ok &= ~unseen[v, u]
    if not ok.any():
        return 0.0
    inside, outside = image[inner[ok, 1], inner[ok, 0]], image[outer[ok, 1], outer[ok, 0]]
    judged = ((np.maximum(inside.max(axis=1), outside.max(axis=1)) > CONTRAST_RGB)
              & (np.minimum(inside.min(axis=1), outside.min(axis=1)) < 255.0 - CONTRAST_RGB))
    changed = np.count_nonzero(judged & (np.linalg.norm(inside - outside, axis=1) > CONTRAST_RGB))
    return float(changed / max(np.count_nonzero(judged), CONTRAST_JUDGED * np.count_nonzero(ok)))
