"""The estimator's own segmentation (our extension, issue 34; not in the paper): which pixels show the robot,
and which of them the end-effector, read off the robot model placed at a calibration, the image's colours
and its depth - no mask handed in.

Region-based trackers (PWP3D, RBOT, SRT3D, ICG and M3T of DLR-RM's 3DObjectTracking) learn colour
statistics inside and outside an object's projected outline and read each pixel's foreground probability
off them. Ours sums three log-odds per pixel: where the pixel lies against the predicted outline (a ramp
across a band as wide as the calibration is uncertain, so only the band is decided by the image), the
colour histograms learned online from the frames' confident pixels, and the depth's agreement with the
model's surface next to the pixel (a pixel whose depth lies far behind it sees past the robot, one far in
front sees an occluder; a stereo hole says nothing). The robot's probability is what the outline term fits;
its 0.5 level is the robot's mask and, where the nearest model part is the end-effector, the end-effector's.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from feepe.optimize import robust_sigma
from feepe.silhouette import iou, outline_pixels

BINS = 16  # colour histogram levels per RGB channel (16^3 bins), as RBOT's 32^3 on a smaller image
PRIOR_LOGODDS = 4.0  # the ramp's log-odds at the band's edges (P = 0.98 inside, 0.02 outside). Inside it stays
# there, so depth that clearly contradicts the model (DEPTH_CLIP) outweighs it: an occluder deep inside the outline;
# outside it keeps falling, PRIOR_LOGODDS per band width, to PRIOR_FLOOR: what lies bands away from where the
# robot can be is not robot, whatever the floor it touches or its colour say
PRIOR_FLOOR = -30.0
COLOUR_CLIP = 3.0  # a histogram ratio counts at most this much: a colour seen once must not decide
DEPTH_CLIP = (-6.0, 4.5)  # depth's log-odds range: a pixel far behind the model is firm evidence
DEPTH_RANGE_M = 3.0  # the background's depth spread: its likelihood is uniform over it
LOCAL_PX = 20.0  # background colours are learned within this distance of the robot's outline
EDGE_PX = 2.0  # and neither they nor the robot's this close to it
DEPTH_STEP_M = 0.05  # neighbouring depths this far apart: a depth edge (the robot's outline against what is behind)
DEPTH_EDGE_PX = 3  # a stereo camera's depth says nothing this close to a depth edge: it spreads the nearer
# surface's depth across the edge (foreground fattening: block matching's window straddles it), so there it would
# paint the background next to the robot as robot; colour and the outline prior decide those pixels
MIN_DEPTH_SIGMA_M = 0.01  # the depth term's scale at least: a few millimetres of calibration error and exact depth
NOISY_PER_M = 5e-4  # a depth image rougher than this (`depth_noise`, m at 1 m) is a sensor's, whose edges are
# fattened; exact depth's edges are the sharpest cue there is (mini scene 7, 8 frames with no mask: 0.2-0.6 mm with
# them, 1.0-3.5 mm without). Measured on mini-stereo's first frames: exact depth 0, the D435 model 4.8-8.7e-3.
# (Before: the depth's spread about the model above 15 mm; a stereo camera's is 14-19 mm, so its edges were read
# in every other frame.)
GIVEN_LOGODDS = 2.0  # a handed-in mask's pull at full trust: below the outline prior's and the depth's clear
# verdicts, so a segmenter's blob far off the predicted outline or a hole where the depth sees the robot stays
# overruled; it decides where the estimator's own evidence is weak (the band, no depth, ambiguous colours)
GIVEN_TRUST_IOU = (0.5, 0.9)  # its trust rises from 0 to 1 as its IoU with the estimator's own mask does
GIVEN_TILE_PX = 24  # once a calibration stands, a handed-in mask is judged region by region, in tiles this wide
GIVEN_TRUST_PX = (1.0, 2.0)  # and its trust there falls from 1 to 0 as it lies farther from the estimator's own
# outline, in pixels on average: own masks then follow the model placed to a pixel or less (IoU 0.93-0.97 against
# the truth), so a region where a segmenter's mask lies farther off holds its error (a boundary moved, a blob, a hole)


@dataclass
class ModelView:
    """The robot model placed in one image: each pixel's nearest part (-1 off the robot) and depth, both
    carried into the band around the outline from the nearest model pixel, and the signed distance to the
    predicted outline (px, > 0 inside)."""
    part: np.ndarray  # (H, W) int: nearest model part (0 the end-effector), -1 where no part is drawn
    depth: np.ndarray  # (H, W) metres: the model's depth at the pixel or at its nearest model pixel
    inside: np.ndarray  # (H, W) signed distance to the predicted outline, px, > 0 inside


def model_view(depth: np.ndarray, part: np.ndarray) -> ModelView:
    """From the robot's rendered depth (m, 0 off it) and nearest part (-1 off it), as
    `PartsSilhouette.render_parts` gives them."""
    drawn = part >= 0
    if not drawn.any():
        return ModelView(part, depth, np.full(drawn.shape, -np.inf))
    off = (~drawn).astype(np.uint8)
    outside, label = cv2.distanceTransformWithLabels(off, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    on = np.flatnonzero(drawn.ravel())  # labels number the drawn pixels in row-major order
    nearest = on[label.ravel() - 1].reshape(drawn.shape)
    inside = cv2.distanceTransform(drawn.astype(np.uint8), cv2.DIST_L2, 5)
    signed = np.where(drawn, inside - 0.5, 0.5 - outside)
    return ModelView(part.ravel()[nearest], depth.ravel()[nearest], signed.astype(np.float32))


class ColourModel:
    """Robot and background colour histograms, updated online (RBOT's alpha-blend of frame histograms)."""

    def __init__(self, rate: float = 0.3):
        self.rate = rate
        self.fg: np.ndarray | None = None
        self.bg: np.ndarray | None = None

    @staticmethod
    def bins(rgb: np.ndarray) -> np.ndarray:
        q = (np.asarray(rgb, np.uint16) * BINS) >> 8
        return (q[..., 0] * BINS + q[..., 1]) * BINS + q[..., 2]

    def update(self, rgb: np.ndarray, fg: np.ndarray, bg: np.ndarray) -> None:
        """Learn from the pixels `fg` (robot) and `bg` (around it)."""
        b = self.bins(rgb)
        if fg.sum() < 50 or bg.sum() < 50:
            return
        new_fg = np.bincount(b[fg], minlength=BINS**3).astype(float)
        new_bg = np.bincount(b[bg], minlength=BINS**3).astype(float)
        new_fg /= new_fg.sum()
        new_bg /= new_bg.sum()
        if self.fg is None:
            self.fg, self.bg = new_fg, new_bg
        else:
            self.fg = (1 - self.rate) * self.fg + self.rate * new_fg
            self.bg = (1 - self.rate) * self.bg + self.rate * new_bg

    def learn(self, rgb: np.ndarray, seen: "Segmentation") -> None:
        """Robot colours from its confident pixels, background colours from the confident pixels around it
        (within LOCAL_PX of the predicted outline: the local background, as RBOT's local regions); neither
        within EDGE_PX of the outline, where pixels blend the two."""
        inside = seen.view.inside
        self.update(rgb, (seen.probability > 0.9) & (inside >= EDGE_PX),
                    (seen.probability < 0.1) & (inside <= -EDGE_PX) & (inside > -LOCAL_PX))

    def logodds(self, rgb: np.ndarray) -> np.ndarray:
        """log P(colour | robot) / P(colour | background) per pixel; 0 before anything was learned."""
        if self.fg is None:
            return np.zeros(np.shape(rgb)[:2], np.float32)
        eps = 1.0 / BINS**3
        ratio = np.log((self.fg + eps) / (self.bg + eps)).astype(np.float32)
        return np.clip(ratio[self.bins(rgb)], -COLOUR_CLIP, COLOUR_CLIP)


def depth_noise(depth: np.ndarray) -> float:
    """How rough the depth image is: the robust spread of each depth's difference from its 5 x 5 median,
    divided by depth squared (a stereo camera's error grows so), in metres at 1 m. Rendered exact depth is
    smooth (0); a sensor's is not."""
    z = np.asarray(depth, np.float32)
    median = cv2.medianBlur(z, 5)
    valid = (z > 0) & (median > 0)
    if np.count_nonzero(valid) < 50:
        return 0.0
    return robust_sigma((z[valid] - median[valid]) / z[valid] ** 2)


def is_sensor_depth(depth: np.ndarray) -> bool:
    """A sensor's depth (rougher than NOISY_PER_M), not rendered exact depth: its edges spread and its
    surfaces carry the matcher's bias, which the estimator allows for."""
    return depth_noise(depth) > NOISY_PER_M


def depth_logodds(depth: np.ndarray, view: ModelView, sigma_m: float, sensor: bool) -> np.ndarray:
    """Per pixel: the observed depth against the model's next to it, robot (Gaussian of the difference)
    against background (uniform over DEPTH_RANGE_M); 0 where the sensor has no depth or no model is near, and
    near depth edges for a sensor's rough depth (`sensor`: `is_sensor_depth`)."""
    d = np.asarray(depth, float) - view.depth
    out = np.log(DEPTH_RANGE_M / (sigma_m * np.sqrt(2 * np.pi))) - 0.5 * (d / sigma_m) ** 2
    out = np.clip(out, *DEPTH_CLIP)
    said = (depth > 0) & (view.depth > 0)
    if sensor:
        said &= ~depth_edges(depth)
    return np.where(said, out, 0.0).astype(np.float32)


def depth_edges(depth: np.ndarray) -> np.ndarray:
    """Pixels within DEPTH_EDGE_PX of a depth step of DEPTH_STEP_M, a hole's rim counted as one: a stereo
    camera loses the background beside a nearer surface (the other camera's view of it is blocked) and
    spreads the nearer depth over the rim it keeps (mini-stereo scene 7 at the true calibration: with holes not
    counted, 2 % of the robot's area in a ring one pixel outside it read as robot by depth)."""
    z = np.asarray(depth, np.float32)
    kernel = np.ones((3, 3), np.uint8)
    step = (cv2.dilate(z, kernel) - cv2.erode(z, kernel)) > DEPTH_STEP_M
    size = 2 * DEPTH_EDGE_PX + 1
    return cv2.dilate(step.astype(np.uint8), np.ones((size, size), np.uint8)) > 0


def robot_logodds(rgb: np.ndarray, depth: np.ndarray | None, view: ModelView, colour: ColourModel,
                  band_px: float, sigma_m: float, sensor: bool, cover: bool = False) -> np.ndarray:
    """log-odds of robot per pixel: the outline prior, the colours and the depth (`sensor`: a sensor's), summed;
    `cover`: on the outline where depth and colour are silent, the pixel's cover (`edge_alpha_logodds`)."""
    prior = np.clip(view.inside / max(band_px, 0.5) * PRIOR_LOGODDS, PRIOR_FLOOR, PRIOR_LOGODDS)
    colours = colour.logodds(rgb)
    said = np.zeros(prior.shape, np.float32) if depth is None else depth_logodds(depth, view, sigma_m, sensor)
    logodds = prior + colours + said
    if not cover:
        return logodds.astype(np.float32)
    alpha = edge_alpha_logodds(rgb, view, logodds, (said == 0) & (np.abs(colours) < EDGE_ALPHA_COLOUR_MAX))
    return np.where(alpha != 0, prior + alpha, logodds).astype(np.float32)  # where read, depth is silent


CONFIDENT_LOGODDS = 2.2  # P(robot) above 0.9 (below 0.1 for the background): ColourModel.learn's confident pixels
EDGE_ALPHA_PX = 2.0  # pixels this close to the predicted outline, undecided by depth and colour: read by their cover
EDGE_ALPHA_WINDOW = 9  # px: the window whose confident pixels give the local robot and background colours
EDGE_ALPHA_CONTRAST = 24.0  # those two colours at least this far apart (8-bit RGB distance) for a cover to be read
EDGE_ALPHA_LOGODDS = 8.0  # log-odds per unit of cover off one half
EDGE_ALPHA_COLOUR_MAX = 1.0  # and only where the colour histograms' log-odds is smaller than this: a blend they
# know neither way (replacing clear histogram verdicts too moved six of 13 stereo renders' ADD down, 0.1-0.8)


def edge_alpha_logodds(rgb: np.ndarray, view: ModelView, logodds: np.ndarray, silent: np.ndarray) -> np.ndarray:
    """log-odds of robot from how much of each pixel the robot covers, for the pixels within EDGE_ALPHA_PX of
    the predicted outline where neither depth nor colour decides (`silent`); 0 elsewhere. A pixel on the outline
    blends the robot's colour F and the background's B: its cover is the share a of c = a F + (1 - a) B, F and B
    the mean colours of the confident robot and background pixels around it. Colour histograms read a blend as
    neither and leave it to the prior, which follows the model as it stands; the cover puts the mask's edge where
    half the pixel is robot (our stereo renders' own masks were fat along a white arm's lit upper edges and thin
    along its lower ones, where a sensor's depth is not read)."""
    read = silent & (np.abs(view.inside) <= EDGE_ALPHA_PX)
    out = np.zeros(read.shape, np.float32)
    _edge_cover(np.ascontiguousarray(rgb, dtype=np.uint8), view.inside, logodds, read, out)
    return out


@numba.njit(cache=True, nogil=True)
def _reflected(i, n):
    """Index i of a row or column of n, reflected at the ends as OpenCV's default border (BORDER_REFLECT_101)."""
    if i < 0:
        return -i
    if i >= n:
        return 2 * (n - 1) - i
    return i


@numba.njit(cache=True, nogil=True)
def _edge_cover(rgb, inside, logodds, read, out):
    """edge_alpha_logodds at the pixels to `read`, the others left as they are. The window's sums go over those
    pixels alone (a box filter over the whole image cost five times the rest of the segmentation's colour work):
    whole colours, so exact; the arithmetic after them in float32, as NumPy did it over the image."""
    h, w = read.shape
    r = EDGE_ALPHA_WINDOW // 2
    confident, edge = np.float32(CONFIDENT_LOGODDS), np.float32(EDGE_PX)
    for v in range(h):
        for u in range(w):
            if not read[v, u]:
                continue
            n_f, n_b = 0, 0
            f0, f1, f2, b0, b1, b2 = 0, 0, 0, 0, 0, 0
            for dv in range(-r, r + 1):
                y = _reflected(v + dv, h)
                for du in range(-r, r + 1):
                    x = _reflected(u + du, w)
                    if logodds[y, x] > confident and inside[y, x] >= edge:
                        n_f += 1
                        f0, f1, f2 = f0 + rgb[y, x, 0], f1 + rgb[y, x, 1], f2 + rgb[y, x, 2]
                    elif logodds[y, x] < -confident and inside[y, x] <= -edge:
                        n_b += 1
                        b0, b1, b2 = b0 + rgb[y, x, 0], b1 + rgb[y, x, 1], b2 + rgb[y, x, 2]
            if n_f == 0 or n_b == 0:
                continue
            F = (np.float32(f0) / np.float32(n_f), np.float32(f1) / np.float32(n_f), np.float32(f2) / np.float32(n_f))
            B = (np.float32(b0) / np.float32(n_b), np.float32(b1) / np.float32(n_b), np.float32(b2) / np.float32(n_b))
            d0, d1, d2 = F[0] - B[0], F[1] - B[1], F[2] - B[2]
            contrast = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if not contrast >= np.float32(EDGE_ALPHA_CONTRAST):
                continue
            c0, c1, c2 = np.float32(rgb[v, u, 0]), np.float32(rgb[v, u, 1]), np.float32(rgb[v, u, 2])
            along = (c0 - B[0]) * d0 + (c1 - B[1]) * d1 + (c2 - B[2]) * d2
            cover = min(max(along / max(contrast * contrast, np.float32(1e-6)), np.float32(0.0)), np.float32(1.0))
            out[v, u] = np.float32(EDGE_ALPHA_LOGODDS) * (cover - np.float32(0.5))


def trust(iou: float) -> float:
    """How much a handed-in mask counts, from its IoU with the estimator's own mask of the same part."""
    low, high = GIVEN_TRUST_IOU
    return float(np.clip((iou - low) / (high - low), 0.0, 1.0))


def local_trust(given: np.ndarray, own: np.ndarray) -> np.ndarray:
    """(H, W) trust in a handed-in mask region by region: in each GIVEN_TILE_PX tile, how far (px) it lies from
    the estimator's own mask on average - the pixels where the two differ per pixel of own outline there (a tile
    with no outline: per pixel) - falling from 1 to 0 over GIVEN_TRUST_PX."""
    (h, w), t = own.shape, GIVEN_TILE_PX

    def per_tile(image: np.ndarray) -> np.ndarray:
        return np.pad(image, ((0, -h % t), (0, -w % t))).reshape((h + -h % t) // t, t, -1, t).sum((1, 3))

    low, high = GIVEN_TRUST_PX
    distance = per_tile(given ^ own) / np.maximum(per_tile(outline_pixels(own)), 1)
    tiles = np.clip((high - distance) / (high - low), 0.0, 1.0).astype(np.float32)
    return np.repeat(np.repeat(tiles, t, 0), t, 1)[:h, :w]


def given_logodds(own: np.ndarray, view: ModelView, robot_mask: np.ndarray | None,
                  ee_mask: np.ndarray | None, regions: bool = False) -> np.ndarray:
    """Handed-in masks as log-odds of robot, each weighed by `trust` in its agreement with the estimator's
    own segmentation `own` (P > 0.5) and, with `regions` (a calibration stands), by `local_trust` region by
    region: a robot mask says robot inside and not robot outside; an end-effector mask alone says robot inside
    and not robot where the model's nearest part is the end-effector."""
    def weight(given: np.ndarray, seen: np.ndarray):
        return trust(iou(given, seen)) * (local_trust(given, seen) if regions else 1.0)

    out = np.zeros(view.part.shape, np.float32)
    if robot_mask is not None:
        out += weight(robot_mask, own) * GIVEN_LOGODDS * np.where(robot_mask, 1.0, -1.0)
    elif ee_mask is not None:
        near_ee = view.part == 0
        out += weight(ee_mask, own & near_ee) * GIVEN_LOGODDS * np.where(ee_mask, 1.0, -1.0 * near_ee)
    return out


def _probability(logodds: np.ndarray) -> np.ndarray:
    return (1.0 / (1.0 + np.exp(-logodds))).astype(np.float32)


def depth_sigma(seen: "Segmentation") -> float:
    """The depth term's scale for the next frames, measured on this one: the robust spread (1.4826 MAD) of the
    sensor's depth about the model's over the confident robot pixels, at least MIN_DEPTH_SIGMA_M. A stereo
    camera's depth spreads centimetres about a robot at a metre (D435 model: 5-95 % within -28..+34 mm on
    mini-stereo at the true calibration); a fixed 1 cm would read a tenth of the robot as background."""
    on = seen.robot & (seen.view.inside >= EDGE_PX) & (seen.depth > 0) & (seen.view.depth > 0)
    if np.count_nonzero(on) < 50:
        return MIN_DEPTH_SIGMA_M
    return max(MIN_DEPTH_SIGMA_M, robust_sigma(seen.depth[on] - seen.view.depth[on]))


@dataclass
class Segmentation:
    """One frame as the estimator segmented it at a calibration, and what it needs to do so again once the
    calibration moves."""
    rgb: np.ndarray
    depth: np.ndarray
    T_cam_base: np.ndarray  # the calibration the model was placed at
    view: ModelView
    probability: np.ndarray  # (H, W) P(robot)
    robot: np.ndarray  # (H, W) bool: the robot's visible mask, P > 0.5
    ee: np.ndarray  # (H, W) bool: those of its pixels whose nearest model part is the end-effector
    robot_mask: np.ndarray | None = None  # the masks handed in, if any: segmenting again weighs them again
    ee_mask: np.ndarray | None = None
    sensor_depth: bool = False  # `depth` is a sensor's (`is_sensor_depth`), judged once per segmentation
    cover: bool = False  # its outline read by the pixels' cover (`edge_alpha_logodds`)


def segment(parts, T_cam_base: np.ndarray, T_base_parts: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
            K: np.ndarray, colour: "ColourModel", band_px: float, sigma_m: float = MIN_DEPTH_SIGMA_M,
            robot_mask: np.ndarray | None = None, ee_mask: np.ndarray | None = None,
            cover: bool = False, sensor: bool | None = None, regions: bool = False) -> Segmentation:
    """`parts`: the robot's PartsSilhouette (the end-effector first), placed at T_cam_base by `T_base_parts`.
    The depth's scale `sigma_m` holds a stereo camera's noise and a few millimetres of calibration error.
    `robot_mask` / `ee_mask`: masks handed in (a segmenter's), a prior weighed by their agreement. `cover`: the
    outline's pixels read by how much of them the robot covers, once a calibration stands. `sensor`: whether the
    depth is a sensor's, where a segmentation of the same frame judged it already (`Segmentation.sensor_depth`).
    `regions`: the handed-in masks judged region by region too (`local_trust`), where the model is placed to a
    pixel or two (a calibration stands, or a frame's refined one)."""
    T_cam_parts = np.einsum("ij,njk->nik", T_cam_base, T_base_parts)
    view = model_view(*parts.render_parts(T_cam_parts, K, depth.shape))
    has_depth = bool((depth > 0).any())
    sensor = has_depth and (is_sensor_depth(depth) if sensor is None else sensor)
    logodds = robot_logodds(rgb, depth if has_depth else None, view, colour, band_px, sigma_m, sensor, cover)
    if robot_mask is not None or ee_mask is not None:
        logodds = logodds + given_logodds(logodds > 0, view, robot_mask, ee_mask, regions)
    probability = _probability(logodds)
    robot = probability > 0.5
    return Segmentation(rgb, depth, np.asarray(T_cam_base, float), view, probability, robot,
                        robot & (view.part == 0), robot_mask, ee_mask, sensor, cover)
