"""FEEPE online: fed frame by frame, returns the end-effector pose and the camera-to-base calibration.

Variants (the paper's ablation): A = PnP only (best candidate by inliers); B = + optimisation over the
current frame's candidates; C = + key frames from the memory pool; D = + symmetry disambiguation (full).
Two extensions of ours, off in the paper's variants: depth alignment (`icp`, feepe/icp.py) and silhouette
refinement (`refine="silhouette"`, feepe/silhouette.py).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from threadpoolctl import ThreadpoolController

from feepe.backbones import DEFAULT as DEFAULT_BACKBONE
from feepe.backbones import get_backbone
from feepe.candidates import FrameCandidates, SingleFrameOptions, frame_candidates
from feepe.centres import CentreTrack, observed_centre
from feepe.icp import (PlaneTerm, SurfaceModel, associate, depth_agreement, depth_distances, observed_cloud,
                       robust_scale, sensor_plane_term, without_window_bias)
from feepe.memory import MemoryEntry, MemoryPool
from feepe.motion import CLIP_FRAMES, MotionClip, MotionFit, motion_starts
from feepe.onboarding import TemplateBank, onboard
from feepe.optimize import OptimizeOptions, optimize, reprojection_px, stack
from feepe.registration import (DepthFit, SceneSearch, contrast_along, contrast_image, depth_fit, hidden,
                                is_new, outline_contrast)
from feepe.robot_starts import RobotSamples, observed_points, robot_starts
from feepe.segmentation import MIN_DEPTH_SIGMA_M, ColourModel, ModelView, Segmentation, depth_sigma, segment
from feepe.silhouette import (PartsSilhouette, SilhouetteModel, contour_fit, contour_term, depth_planes, iou_bound,
                              mask_view, mean_iou, placed, strided)
from feepe.symmetry import consensus
from kernel.errors import UserError
from kernel.transforms import inv_T, transform_points

VARIANTS = ("A", "B", "C", "D")
REFINEMENTS = ("none", "silhouette", "silhouette+depth")
SILHOUETTES = ("ee", "robot")
GIVEN_MASKS = ("truth", "prior")
IOU_STRIDE = 2  # the refinement's decisions compare mask IoUs on every second pixel
RENDERER = "zbuffer"  # how the refinement renders masks and tests outlines (feepe/raster.py; before: Embree rays)
CHOICE = "iou x scaled depth agreement"  # the refinement with depth picks among descents so (before: IoU alone)
BAND_START_PX = 8.0  # no mask given: the segmentation's band around a calibration that is not yet refined
BAND_MIN_PX = 2.0  # and around one just refined
BAND_PER_PX = 3.0  # the next frame's band: this many times how far (px) the frame's refinements moved the robot
MAX_HYPOTHESES = 5  # no mask given: the registrations' hypotheses kept and judged as frames arrive
ACCEPT_AGREE = 0.5  # no mask given: a first calibration needs this share of the robot's depth pixels that nothing
# hides (the sensor not nearer than the model) to agree
ACCEPT_MIN_SHARE = 0.04  # and its depth pixels to cover this share of the image: a sliver of the robot at the
# image's edge (hard-case seed 23, the camera turned away from the arm) is explained as well by a calibration a
# metre off, placing another link there (accepted at 1.4 % and 2.2 %; plain seed-23 segments first at 7-23 %)
ACCEPT_UNHIDDEN = 0.5  # nothing to hide at least this share of them
ACCEPT_SEEN_THROUGH = 0.15  # and no more than this share seen through
ACCEPT_CONTRAST = 0.8  # and the image's colour to change across this share of its outline (registration.py)
SURE_AGREE = 0.6  # a first calibration clearing those bars is taken at once only if this share agrees,
SURE_SEEN_THROUGH = 0.05  # no more than this share is seen through
SURE_CONTRAST = 0.9  # and the colour changes across this share of its outline; else it is kept as the next frame's
KEPT_SCORE = 0.9  # start and taken on a frame that it still passes and that it explains, before it is refined
# there, with this share of the depth score (registration.DepthFit.score) its refinement there reaches: the new
# frame bears it out. At the truth over the 79 first-frame tests with the robot in view of 12 stereo development
# renders: agreement 0.62-1.00, seen through 0-4.6 %, contrast 0.91-1.00. A UR5e start 27 cm / 23 deg off (seed 59
# scene 8) passed at 0.52, 8.3 %, 0.87; refined over the next frames it cleared the higher bars 10 cm off, but
# each new frame scored it at 0.57-0.75 of its refinement there. True starts kept so (hard-case exit scene 16, the
# arm entering the view: contrast 0.84-0.86 at the truth) scored 0.95-1.05, though each frame's refinement, alone
# on a partly seen arm, moved them 6-15 mm
SURE, PASSES, FAILS = "sure", "passes", "fails"  # a first calibration's verdicts on a frame
MOTION_MIN_FRAMES = 8  # RGB only, no mask: the robot is first searched for by its motion once this many frames are
# seen (feepe/motion.py; frames 0 and 1 of a mini segment differ on 2 % of the pixels, frames 0 and 7 on a quarter)
MOTION_EVERY = 4  # and again every this many frames until a calibration is accepted
RGB_CONTRAST = SURE_CONTRAST  # RGB only: the colour must change across this share of a first calibration's
# outline, and across ACCEPT_CONTRAST's on every later frame, or the calibration is dropped. Without depth the
# colour is the one check on the pose beside the motion, and the motion alone can prefer a robot placed decimetres
# off along the camera's ray: `data/mini` scene 10 (UR5e + Robotiq-3F) was accepted 30 cm off at 0.84, then read
# 0.70-0.83 on each later frame; the RGB-only estimates of 11 other segments (`data/mini`, seed 19) read 0.95-1.00
# on every frame, and one 12-13 mm off (seed 19's UR10e + Robotiq-3F) 0.88-0.90
MOTION_KEPT = 0.95  # RGB only: a first calibration, refined, must keep this share of the best motion score the
# search found on the frames so far (motion.py): the outline refinement must not have taken it elsewhere. The
# scores themselves tell little alone: shadows cost the true calibration of mini scene 4 half of its score
RGB_START_ROUNDS = 10  # RGB only: a first calibration is refined at its frame up to this many times more (_settled)
SEGMENT_AGAIN_PX = 0.25  # with a calibration standing, a frame is segmented again once its refinement moved it this far
COLOUR_ROUNDS = 2  # a segment's first estimate is refined again at most this many times once colours are learned
# from it (four stereo development renders, AUC@1cm ADD: once 85.87, 87.70, 86.51, 78.24; up to twice 85.87, 87.72,
# 86.51, 80.06: seed 59's Panda + Robotiq-3F 8.4 -> 2.9 mm off at frame 0, its UR5e + 2F-140 found a frame earlier)
START_ROUNDS = 2  # a first estimate that does not explain its frame yet is refined again at its own segmentation
# this many times: a hypothesis a few centimetres off comes in within one frame, not over several
OWN_MASKS_MIN_SIGMA_PX = 2.0  # no mask given: the outline's scale beside depth at least this. Our own masks err by a
# bias of about a pixel (never averaged away over frames, as a segmenter's noise is), so the robot's depth
# decides what the outline cannot (six seed-0 stereo segments, --masks none, AUC@1cm ADD / calibration after 15
# frames: 0.25 px (silhouette_min_sigma_px) 84.27 / 1.45 mm, 1 px 87.92 / 1.45 mm, 2 px 89.36 / 1.37 mm)
ROBOT_DEPTH_POINTS = 12000  # no mask given: the robot's depth points per frame in the refinement (on mini's 320 x
# 240 images about every pixel of its eroded mask). Its outline fixes the robot across the image and its distance
# only through its size, which our segmentation's sub-pixel bias shifts by millimetres; the depth weighs with its
# points' number (six seed-0 stereo mini segments, --masks none, AUC@1cm ADD / calibration after 15 frames: 600
# points 74.26 / 2.0 mm, 2000 78.94 / 1.54 mm, 5000 81.88 / 1.45 mm, 12000 84.27 / 1.45 mm)
# The refinement's solves (OptimizeOptions) stop once a step promises less than MIN_DECREASE of the cost
# (b882845; 1e-5 and 1e-4 took 28.4 and 26.8 against 29.7 ms/frame and moved poses: docs/history.md, eighth
# step), or once a step that failed moves the pose less than MIN_STEP (rad and m: 1 um at the model; 6064148:
# 395 of 1701 solves had raised the damping from 1e-7 past 1e8 with their steps below 1 um after 4-6 trials,
# docs/history.md, tenth step). Each solve takes at most SOLVE_ITERATIONS steps; a stage's rounds of contour
# extraction and solve end once a solve moves the calibration less than ROUND_MOVED_M, and depth alignment's
# rounds once one moves it less than ICP_MOVED_M (set with the refinement, fcb078c, and with depth alignment,
# 7d2aed9; no measurement of these three is recorded).
MIN_DECREASE = 1e-6
MIN_STEP = 1e-6
SOLVE_ITERATIONS = 5
ROUND_MOVED_M = 1e-4
WARM_ROUND_MOVED_M = 3e-4  # with the estimator's own masks and a calibration standing, a frame's rounds end once a
# solve moves it less than this: the next frame goes on from it. Seed 131's later frames: the first solve moved it a
# median 0.17 mm and 57 of 81 went on at 0.1 mm, the second round moving a median 0.03 mm; at 0.3 mm later frames
# 87.5 -> 77.5 ms, ADD on seeds 131, 157, 151, 137 +0.00, -0.01, -0.06, -0.12, after 15 frames within 0.01 mm
# A descent that draws the model smaller than this, and than half its start did, has run off: its start is lost
# (its IoU is nil), and going on cost seconds, as every contour point of a robot a pixel across tests each of its
# triangles (seed 59's UR10e + 2F-85: a start 2.4 m away ran to 58-820 m, 16 of its first frame's 23 s).
MIN_SPAN_PX = 16.0
ICP_MOVED_M = 1e-5
# The optimisation and the refinement multiply many small matrices (normal equations of N x 6 Jacobians,
# N x 3 points by 3 x 3 rotations). OpenBLAS's threads cost more than they save there: a 10000 x 6 normal
# matrix took 0.15 ms on one thread and 1.4-23 ms on two while the cores were busy. Those stages run on one.
_BLAS = ThreadpoolController()


@dataclass
class FeepeOptions:
    variant: str = "D"
    k_f: int = 8
    memory_threshold_deg: float = 10.0
    symmetry_tolerance_deg: float = 20.0
    icp: bool = False  # our depth-alignment extension (feepe/icp.py); the paper's variants run without it
    icp_iterations: int = 5
    icp_gate_m: float = 0.02
    icp_sigma_m: float = 0.002
    refine: str = "none"  # "silhouette": our multi-frame mask alignment (feepe/silhouette.py); "+depth": with depth
    silhouette: str = "ee"  # the outline fitted: "ee" (the paper's input, the end-effector's mask) or "robot"
    given_masks: str = "truth"  # masks handed in: taken as they are, or ("prior") one more signal of the
    # estimator's own segmentation, weighed by how well they agree with it (needs silhouette="robot")
    silhouette_sigmas_px: tuple = (4.0, 2.0, 1.0)  # coarse to fine: the robust kernel's scale per stage
    silhouette_rounds: int = 3  # contour re-extractions per stage
    silhouette_starts: int = 3  # starting calibrations refined; the best mask IoU is kept
    silhouette_position_starts: bool = True  # also start from the calibration the end-effector's positions imply
    silhouette_switch_iou: float = 0.05  # another start must beat the last calibration's IoU by this to be tried
    silhouette_min_sigma_px: float = 0.25  # with depth, the finest stage's scale: the masks' measured spread, at least this
    silhouette_depth_tolerance: float = 2.0  # standard errors depth may worsen the mean contour distance by
    robot_start_frames: int = 3  # silhouette="robot": first frames that also start from the robot's depth
    silhouette_key_frames: int = 16  # key frames the refinement fits (FEEPE D's solve keeps k_f)
    silhouette_memory_m: float = 0.005  # with the refinement, a frame whose end-effector moved this far is a new view
    silhouette_refit_growth: float = 0.0  # new key frames refit once the memory grew by this fraction (0: each)
    depth_sigma_m: float = 0.002  # noise shape sigma_m + sigma_z2 * z^2 (m), scaled by the measured spread;
    depth_sigma_z2: float = 0.0036  # z^2 factor: Intel's D435 RMS model, subpixel 0.08 / (f 447 px x 0.05 m)
    depth_window_px: float = 1.5  # no mask given: a stereo camera's matching window (a Gaussian's sigma, image
    # px), whose bias over the robot's curved surfaces is taken off its depth (feepe.icp.window_bias; 0: not);
    # fitted to our simulated D435's error against depth_gt at 320 x 240 (1.3-1.6 px), not to the results
    single: SingleFrameOptions = field(default_factory=SingleFrameOptions)
    optimize: OptimizeOptions = field(default_factory=OptimizeOptions)

    def __post_init__(self):
        if not self.silhouette_refit_growth >= 0:
            raise UserError(f"refit growth {self.silhouette_refit_growth} must be >= 0 (0: refit on each new key frame)")
        for name, low in (("k_f", 0), ("memory_threshold_deg", 0), ("symmetry_tolerance_deg", 0),
                          ("icp_iterations", 0), ("icp_gate_m", 0), ("silhouette_rounds", 1),
                          ("silhouette_starts", 1), ("robot_start_frames", 0), ("silhouette_key_frames", 0)):
            if not getattr(self, name) >= low:
                raise UserError(f"FeepeOptions.{name} = {getattr(self, name)} must be >= {low}")
        if not self.depth_window_px >= 0:
            raise UserError(f"FeepeOptions.depth_window_px = {self.depth_window_px} must be >= 0 (0: no window bias)")
        for name in ("icp_sigma_m", "silhouette_min_sigma_px", "depth_sigma_m", "silhouette_memory_m"):
            if not getattr(self, name) > 0:
                raise UserError(f"FeepeOptions.{name} = {getattr(self, name)} must be > 0")
        if not self.silhouette_sigmas_px or not all(s > 0 for s in self.silhouette_sigmas_px):
            raise UserError(f"FeepeOptions.silhouette_sigmas_px = {self.silhouette_sigmas_px}: give one or more "
                            "positive scales, coarse to fine")
        if self.variant not in VARIANTS:
            raise UserError(f"FEEPE variant {self.variant!r} unknown; choose one of {', '.join(VARIANTS)}")
        if self.icp and self.variant == "A":
            raise UserError("variant A is PnP only; depth alignment (icp) needs variant B, C or D")
        if self.refine not in REFINEMENTS:
            raise UserError(f"refinement {self.refine!r} unknown; choose one of {', '.join(REFINEMENTS)}")
        if self.refine != "none" and self.variant == "A":
            raise UserError("variant A is PnP only; silhouette refinement needs variant B, C or D")
        if self.silhouette not in SILHOUETTES:
            raise UserError(f"silhouette {self.silhouette!r} unknown; choose one of {', '.join(SILHOUETTES)}")
        if self.given_masks not in GIVEN_MASKS:
            raise UserError(f"given_masks {self.given_masks!r} unknown; choose one of {', '.join(GIVEN_MASKS)}")
        if self.given_masks == "prior" and self.silhouette != "robot":
            raise UserError("given_masks 'prior' weighs the masks against the estimator's own segmentation of the "
                            "robot; it needs silhouette 'robot'")
        if self.silhouette != "ee" and self.refine == "none":
            raise UserError(f"silhouette {self.silhouette!r} is what the refinement fits; it needs refine "
                            "silhouette or silhouette+depth")

    @property
    def depth_in_refinement(self) -> bool:
        return self.refine == "silhouette+depth"

    @property
    def needs_surface(self) -> bool:
        """The depth terms (icp, silhouette+depth) align to surface samples of the model."""
        return self.icp or self.depth_in_refinement


def fitting_own_masks(opts: FeepeOptions, depth: bool, refine_chosen: bool = False) -> FeepeOptions:
    """With no mask given, or masks as a prior, the estimator segments the robot itself and fits the robot's
    outline to that segmentation (the refinement on, `silhouette="robot"`): with depth where there is depth,
    unless a refinement was chosen (six seed-0 segments per depth, no mask: exact 91.34 -> 98.80 ADD, stereo
    33.33 -> 40.56; history.md)."""
    refine = opts.refine if refine_chosen else "silhouette+depth" if depth else "silhouette"
    return replace(opts, silhouette="robot", refine=refine)


def load_models(path: Path, opts: FeepeOptions) -> tuple[SurfaceModel | None, SilhouetteModel | None]:
    """What our extensions need of the end-effector's BOP model (.ply, mm): surface samples for the depth
    terms, the mesh for the silhouette."""
    return (SurfaceModel.from_ply(path) if opts.needs_surface else None,
            SilhouetteModel.from_ply(path) if opts.refine != "none" else None)


@dataclass
class _Fitted:
    """The last refinement: the memory's size then, its calibration, the key frames it fitted and their mean mask
    IoU there, measured only once a later frame asks (one that adds no key frame; before, every refinement measured
    it on every key frame)."""
    pool_size: int
    T_cam_base: np.ndarray
    frames: list
    iou: float | None = None


@dataclass
class RobotView:
    """The whole robot in one frame, for `silhouette="robot"`: its visible mask (every link and the
    end-effector; a robot segmenter's output; None when no mask is given) and the arm links' poses from
    forward kinematics, in the order of the `arm` models given to `Estimator.reset`."""
    mask: np.ndarray | None  # (H, W) bool
    T_base_links: np.ndarray  # (n, 4, 4) metres


@dataclass
class FrameResult:
    T_cam_ee: np.ndarray | None  # None: no estimate for this frame
    T_cam_base: np.ndarray | None
    score: float  # current-frame matches consistent with the final pose; with no mask given (the estimator's own
    # segmentation), the robot model's mask IoU at the calibration against that segmentation of the frame
    n_candidates: int
    n_key_frames: int
    timings: dict  # ms per stage and "total"
    masks: dict | None = None  # with no mask given: the estimator's own "ee" and "robot" visible masks, (H, W) bool


SILHOUETTE_OPTIONS = ("refine", "silhouette", "silhouette_sigmas_px", "silhouette_rounds", "silhouette_starts",
                      "silhouette_position_starts", "silhouette_switch_iou", "silhouette_min_sigma_px",
                      "silhouette_depth_tolerance", "silhouette_key_frames", "silhouette_memory_m",
                      "depth_sigma_m", "depth_sigma_z2")


def describe(opts: FeepeOptions, backbone) -> dict:
    """Every option that changes the estimates, JSON-able. The refinement's options appear only when it is
    on: they change nothing otherwise, and runs stored before it existed keep their identity."""
    out = asdict(opts)
    if opts.refine == "none":
        out = {k: v for k, v in out.items() if k not in SILHOUETTE_OPTIONS}
    if opts.silhouette != "robot":  # runs of the end-effector outline keep their identity
        out.pop("robot_start_frames")
    if not opts.silhouette_refit_growth:  # as runs before the option existed
        out.pop("silhouette_refit_growth")
    if opts.given_masks == "truth":  # likewise
        out.pop("given_masks")
    if opts.refine != "none":  # the refinement's estimates changed with the rasteriser (history.md, sixth
        out["silhouette_renderer"] = RENDERER  # step): a run stored before it is not resumed by this code
    if opts.depth_in_refinement:  # so did its choice among descents, with depth (history.md, eleventh step)
        out["silhouette_choice"] = CHOICE
    return {**out, "backbone": backbone.options()}


class Estimator:
    def __init__(self, bank: TemplateBank, backbone, options: FeepeOptions | None = None,
                 model: SurfaceModel | None = None, silhouette: SilhouetteModel | None = None):
        self.bank, self.backbone, self.model, self.silhouette = bank, backbone, model, silhouette
        self.opts = options or FeepeOptions()
        if self.opts.needs_surface and model is None:
            raise UserError("depth alignment (icp) needs the end-effector model: pass model=SurfaceModel.from_ply(...)")
        if self.opts.refine != "none" and silhouette is None:
            raise UserError("silhouette refinement needs the end-effector model: "
                            "pass silhouette=SilhouetteModel.from_ply(...)")
        self.reset()

    @classmethod
    def from_templates(cls, folder: Path, backbone: str = DEFAULT_BACKBONE, options: FeepeOptions | None = None,
                       cache_dir: Path | None = None, model_path: Path | None = None,
                       **backbone_kwargs) -> "Estimator":
        """model_path (the BOP .ply, mm) is needed only for our extensions (icp, silhouette refinement)."""
        net = get_backbone(backbone, **backbone_kwargs)
        opts = options or FeepeOptions()
        model, silhouette = load_models(model_path, opts) if model_path else (None, None)
        return cls(onboard(folder, net, opts.single.pad, cache_dir=cache_dir), net, opts, model, silhouette)

    def options(self) -> dict:
        return {**describe(self.opts, self.backbone), "n_templates": len(self.bank)}

    def reset(self, arm: list[SilhouetteModel] | None = None) -> None:
        """Start a new sequence (a new camera placement): the memory and the last calibration go. `arm`:
        the arm links' meshes (link frames) that `silhouette="robot"` fits beside the end-effector."""
        if arm and self.opts.silhouette != "robot":
            raise UserError("reset(arm=...) gives the arm's link meshes to the robot's outline; build the Estimator "
                            "with FeepeOptions(refine='silhouette', silhouette='robot') to fit it, or leave arm out")
        self.parts = PartsSilhouette([self.silhouette, *(arm or [])]) if self.silhouette is not None else None
        self._robot_samples = RobotSamples.of([p.mesh for p in self.parts.parts]) if arm else None
        self.pool = MemoryPool(self.opts.memory_threshold_deg,
                               self.opts.silhouette_memory_m if self.opts.refine != "none" else np.inf)
        self.T_cam_base: np.ndarray | None = None
        self.frame = 0
        self._fitted: _Fitted | None = None  # the last refinement
        self.centres = CentreTrack(self.silhouette.centre) if self.silhouette is not None else None
        self.colour = ColourModel()  # no mask given: the robot's and the background's colours, learned online
        self._hypotheses: list[list] = []  # no mask given: [T_cam_base, summed depth score] from the registrations
        self._passing: np.ndarray | None = None  # and the first calibration that passed the last frame, not yet taken
        self._band_px = BAND_START_PX
        self._depth_sigma = MIN_DEPTH_SIGMA_M  # no mask given: the segmentation's depth scale, measured per frame
        self._own_masks = False  # whether the refinement fits the estimator's own masks (no mask, or masks as a prior)
        self._clip = MotionClip()  # no mask and no depth: the frames so far, coarse, for the motion search
        self._waiting: list[tuple] = []  # and those before any hypothesis (the latest CLIP_FRAMES), kept to join the
        # memory once one is accepted

    def step(self, rgb: np.ndarray, depth: np.ndarray | None, mask: np.ndarray | None, K: np.ndarray,
             T_base_ee: np.ndarray, robot: RobotView | None = None) -> FrameResult:
        """One frame, online. `mask` is the end-effector's visible mask; `robot` is needed for (and only
        read by) the robot silhouette. `mask` None: no mask of any kind is given, and the estimator finds
        the robot and segments it itself (feepe/registration.py, feepe/segmentation.py): it then needs the
        arm's links (reset(arm=...)) and each frame's link poses (robot=RobotView(None, T_base_links)).
        With `given_masks="prior"` the masks handed in (`mask`, `robot.mask`) enter that segmentation as one
        more signal. `depth` None: an RGB camera (as depth 0 everywhere: no depth)."""
        depth = np.zeros(np.shape(rgb)[:2]) if depth is None else depth
        _check_inputs(rgb, depth, mask, K, T_base_ee)
        t_start = time.perf_counter()
        self._own_masks = mask is None or self.opts.given_masks == "prior"
        if self._own_masks:
            return self._step_unmasked(rgb, np.asarray(depth, float), np.asarray(K, float),
                                       np.asarray(T_base_ee, float), robot, t_start,
                                       None if mask is None else np.asarray(mask, bool))
        found = frame_candidates(rgb, depth, np.asarray(mask, bool), K, self.bank, self.backbone, self.opts.single)
        if found is None:
            found = FrameCandidates(np.eye(3), [], 0, {})
        if self.opts.needs_surface:
            found.cloud = observed_cloud(np.asarray(depth, float), np.asarray(mask, bool), K)
        if self.opts.refine != "none":
            if self.opts.silhouette == "robot":
                robot = _check_robot(robot, mask.shape, len(self.parts.parts) - 1)
                found.silhouette = mask_view(robot.mask, K, depth)
                found.parts = np.concatenate([np.asarray(T_base_ee, float)[None], robot.T_base_links])
                if self.frame < self.opts.robot_start_frames:
                    t0 = time.perf_counter()
                    found.robot_starts = self._robot_starts(found.parts, robot.mask, depth, mask, K)
                    found.timings["robot_starts"] = 1e3 * (time.perf_counter() - t0)
            else:
                found.silhouette = mask_view(mask, K, depth)
                found.parts = np.asarray(T_base_ee, float)[None]
            if self.opts.silhouette_position_starts:
                self.centres.add(T_base_ee, observed_centre(depth, mask, K))
        timings = dict(found.timings)
        t0 = time.perf_counter()
        with _BLAS.limit(limits=1, user_api="blas"):
            T_cam_base, score, n_keys = self._estimate(found, T_base_ee, timings)
        timings["optimisation"] = 1e3 * (time.perf_counter() - t0) - timings.get("refinement", 0.0)
        self.pool.consider(MemoryEntry(self.frame, T_base_ee, found))
        self.frame += 1
        if T_cam_base is not None:
            self.T_cam_base = T_cam_base
        timings["total"] = 1e3 * (time.perf_counter() - t_start)
        T_cam_ee = None if T_cam_base is None else T_cam_base @ T_base_ee
        return FrameResult(T_cam_ee, T_cam_base, score, len(found.candidates), n_keys, timings)

    def _step_unmasked(self, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, T_base_ee: np.ndarray,
                       robot: RobotView | None, t_start: float, ee_mask: np.ndarray | None = None) -> FrameResult:
        """No mask: the robot is found in the first frames' depth (several hypotheses, judged as frames
        arrive) or, with no depth, by its motion over the first frames (feepe/motion.py), each frame is
        segmented at the calibration so far, the template path crops the predicted end-effector until a
        calibration is accepted, and the robot's outline is fitted to the estimator's own segmentation (on the
        first frame refined again once the colours are learned from the first fit). A frame before any
        hypothesis explains its depth (or the motion and the frame's colours) well is a no-estimate."""
        if self._robot_samples is None:
            raise UserError("with no mask the estimator finds the robot itself: reset(arm=[SilhouetteModel(...), ...]) "
                            "with the arm's link meshes, on an Estimator with silhouette='robot'")
        given = ee_mask is not None and robot is not None and robot.mask is not None  # masks as a prior
        robot = _check_robot(robot, depth.shape, len(self.parts.parts) - 1, masked=given)
        robot_mask = robot.mask
        T_base_parts = np.concatenate([T_base_ee[None], robot.T_base_links])
        timings: dict = {}
        surface = None  # the robot's surface samples placed by this frame's joint states, built once when needed
        has_depth = bool(np.any(depth > 0))
        with _BLAS.limit(limits=1, user_api="blas"):
            if self.T_cam_base is None:
                t0 = time.perf_counter()
                if has_depth:
                    surface = SurfaceModel(*self._robot_samples.placed(T_base_parts))
                    self._judge_hypotheses(surface, T_base_parts, rgb, depth, K)
                else:
                    self._judge_motion(rgb, K, T_base_parts)
                timings["registration"] = 1e3 * (time.perf_counter() - t0)
            T = T_start = self._start(T_base_parts, rgb, depth, K)
            if T is None:
                if not has_depth:
                    self._waiting.append((self.frame, rgb, K, T_base_ee, T_base_parts))
                    del self._waiting[:-CLIP_FRAMES]
                self.frame += 1
                timings["total"] = 1e3 * (time.perf_counter() - t_start)
                return FrameResult(None, None, 0.0, 0, 0, timings)
            t0 = time.perf_counter()
            standing = self.T_cam_base is not None
            seen = segment(self.parts.coarse, T, T_base_parts, rgb, depth, K, self.colour, self._band_px,
                           self._depth_sigma, robot_mask=robot_mask, ee_mask=ee_mask, cover=standing, regions=standing)
            timings["segmentation"] = 1e3 * (time.perf_counter() - t0)
            self._refresh_key_frames(T)
        # once a calibration stands, the template path's starts never beat its warm refinement (four stereo
        # development renders, every pose the same without it): it runs only until one is accepted
        found = (frame_candidates(rgb, depth, seen.ee, K, self.bank, self.backbone, self.opts.single)
                 if self.T_cam_base is None else None)
        if found is None:
            found = FrameCandidates(np.eye(3), [], 0, {})
        timings.update(found.timings)
        found.segmentation, found.parts = seen, T_base_parts
        found.silhouette = mask_view(seen.robot, K, depth)
        found.robot_starts = [h[0] for h in self._hypotheses]
        if self.opts.needs_surface:  # the depth of what the outline fits: the whole robot
            if surface is None:
                surface = SurfaceModel(*self._robot_samples.placed(T_base_parts))
            found.cloud, found.surface = _robot_cloud(seen, K, self.opts.depth_window_px), surface
        if self.opts.silhouette_position_starts:
            self.centres.add(T_base_ee, observed_centre(depth, seen.ee, K))
        t0 = time.perf_counter()
        with _BLAS.limit(limits=1, user_api="blas"):
            colourless = self.colour.fg is None
            T_new, _, n_keys = self._estimate(found, T_base_ee, timings, prior=T)
            timings["optimisation"] = 1e3 * (time.perf_counter() - t0) - timings.get("refinement", 0.0)
            if (self.T_cam_base is not None
                    and self.parts.motion_px(placed(T, found.parts), placed(T_new, found.parts), K) < SEGMENT_AGAIN_PX):
                # the frame's segmentation stands at the refined calibration (a quarter pixel moves the ramp's band
                # and the model's depth by less than their own scales): its colours learned, not drawn again (half
                # of a later frame's segmentation; seeds 131, 157, 151, 137 ADD -0.03..0, after 15 frames the same
                # or 0.03 mm better)
                self._learn(rgb, seen)
            else:
                seen = self._segment_again(T_new, rgb, depth, K, found, timings)
            if colourless and self.colour.fg is not None:  # the first segmentation knew no colours: its outline
                # was the prior's and the depth's; refined again on the colours learned from it, until the robot
                # moves less than a pixel, from that fit alone (the other starts lost to it on this frame already:
                # seeds 131, 103, 151 and held-out 157 the same or better, the first frame's refinement 868 -> 653 ms),
                # with depth at the finest scale only: that fit has descended the coarse ones (seed 131's first frames
                # 1091 -> 1064 ms, its ADD the same to 0.02); RGB only, the motion's first calibration lies centimetres
                # off and keeps them (data/mini's six segments 41.05/45.82, 2.60 mm after 15 frames; 38.22/42.87,
                # 3.03 mm at the finest scale only)
                for _ in range(COLOUR_ROUNDS):
                    T, T_new = T_new, self._refined(T_new, T_base_ee, found, timings, others=False, fine=has_depth)
                    seen = self._segment_again(T_new, rgb, depth, K, found, timings)
                    if self.parts.motion_px(placed(T, found.parts), placed(T_new, found.parts), K) < 1.0:
                        break
            accepted = self.T_cam_base is not None
            if accepted and not has_depth and outline_contrast(seen.view.inside > 0, rgb) < ACCEPT_CONTRAST:
                self._drop()
                accepted = False
            elif not accepted:
                verdict = self._explains(T_new, T_base_parts, rgb, depth, K, seen, has_depth)
                for _ in range(START_ROUNDS):
                    if verdict != FAILS:
                        break
                    T_new = self._refined(T_new, T_base_ee, found, timings)
                    seen = self._segment_again(T_new, rgb, depth, K, found, timings)
                    if self._explains(T_new, T_base_parts, rgb, depth, K, seen, has_depth) != FAILS:
                        verdict = PASSES if has_depth else SURE  # depth: judged at the segmentation it was just
                        # fitted to, so later frames confirm it (RGB only: the motion over the clip judged it)
                accepted = self._accepts(verdict, T_start, T_new, found.parts, rgb, depth, K)
            if accepted and self.T_cam_base is None and self._waiting:
                T_new, seen = self._settled(T_new, T_base_ee, rgb, depth, K, found, timings)
        # the next frame's band: how far this frame's refinements moved the robot from the frame's start
        self._band_px = float(np.clip(BAND_PER_PX * self.parts.motion_px(placed(T_start, T_base_parts),
                                                                       placed(T_new, T_base_parts), K),
                                      BAND_MIN_PX, BAND_START_PX))
        self.pool.consider(MemoryEntry(self.frame, T_base_ee, found), need_candidates=False)
        self.frame += 1
        timings["total"] = 1e3 * (time.perf_counter() - t_start)
        if not accepted:
            return FrameResult(None, None, 0.0, len(found.candidates), n_keys, timings, masks=None)
        self.T_cam_base = T_new
        score = mean_iou(self.parts, T_new, [(found.parts, found.silhouette)], IOU_STRIDE)
        return FrameResult(T_new @ T_base_ee, T_new, score, len(found.candidates), n_keys, timings,
                           masks={"ee": seen.ee, "robot": seen.robot})

    def _segment_again(self, T_new: np.ndarray, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray,
                       found: FrameCandidates, timings: dict) -> Segmentation:
        """The frame segmented again at the refined calibration T_new, and the colours learned from it. Masks handed
        in are judged there region by region (`segmentation.local_trust`): the model placed at a refined calibration
        draws the robot to a pixel or two, so a segmenter's error shows (seed 191's Kinova-3F with `sam` masks as a
        prior: its frame 0 ADD 3.5 -> 1.2 mm, 0.9 with no mask)."""
        t0, before = time.perf_counter(), found.segmentation
        seen = segment(self.parts.coarse, T_new, found.parts, rgb, depth, K, self.colour, BAND_MIN_PX,
                       self._depth_sigma, robot_mask=before.robot_mask, ee_mask=before.ee_mask, cover=before.cover,
                       sensor=before.sensor_depth, regions=True)
        self._learn(rgb, seen)
        found.segmentation, found.silhouette = seen, mask_view(seen.robot, K, depth)
        if found.surface is not None:
            found.cloud = _robot_cloud(seen, K, self.opts.depth_window_px)
        timings["segmentation"] += 1e3 * (time.perf_counter() - t0)
        return seen

    def _learn(self, rgb: np.ndarray, seen: Segmentation) -> None:
        """The colours and the depth's scale the next segmentation reads, from this one."""
        self.colour.learn(rgb, seen)
        self._depth_sigma = depth_sigma(seen)

    def _judge_hypotheses(self, model: SurfaceModel, T_base_parts: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
                          K: np.ndarray) -> None:
        """The robot found again in this frame's depth (feepe/registration.py); every hypothesis so far and
        the new ones scored by their depth agreement on this frame, borne out by the colour across their outline
        (on the coarse grid: the hypotheses are a centimetre or so off before any refinement, and an offset
        of three coarse pixels spans that), summed over the frames seen. Once the whole scene has failed, its
        nearest parts are searched too (registration.near_hypotheses): on the first frame when none of the whole
        scene's hypotheses explains it as it stands (`_coarse_judgement`), on every later one (no calibration was
        accepted), unless a start passed the last frame: that frame's hypotheses are judged on this one, which
        decides whether that start is taken (seed 211's Panda + Shadow Hand, a start passing from frame 1 and taken
        at frame 3, searched 1.0 and 0.7 s in frames 2 and 3 for no hypothesis it took). `model`: the robot's surface
        samples placed by this frame's joint states (base frame)."""
        search = SceneSearch(model, depth, K, seed=self.frame) if self._passing is None else None
        if search is not None:
            self._add_hypotheses(search.hypotheses(near=self.frame > 0))
        colours = _coarse_colours(rgb, K)
        judged = [_coarse_judgement(self.parts, h[0], T_base_parts, colours, depth, K) for h in self._hypotheses]
        if search is not None and self.frame == 0 and all(verdict == FAILS for _, verdict in judged):
            self._add_hypotheses(search.hypotheses(near=True, whole=False))
            judged += [_coarse_judgement(self.parts, h[0], T_base_parts, colours, depth, K)
                       for h in self._hypotheses[len(judged):]]
        for h, (score, _) in zip(self._hypotheses, judged):
            h[1] += score
        self._hypotheses.sort(key=lambda h: -h[1])
        del self._hypotheses[MAX_HYPOTHESES:]

    def _add_hypotheses(self, found: list[np.ndarray]) -> None:
        """New hypotheses join those so far, unscored; one near-equal to a known one does not (is_new)."""
        known = [h[0] for h in self._hypotheses]
        for T in found:
            if is_new(T, known):
                self._hypotheses.append([T, 0.0])
                known.append(T)

    def _judge_motion(self, rgb: np.ndarray, K: np.ndarray, T_base_parts: np.ndarray) -> None:
        """RGB only: the frame joins the clip; from MOTION_MIN_FRAMES on, every MOTION_EVERY frames, the robot is
        searched for by its motion over the clip (feepe/motion.py), and the hypotheses so far are scored again
        on it beside the new ones."""
        self._clip.add(rgb, K, self._robot_samples.placed(T_base_parts)[0])
        n = len(self._clip)
        if n < MOTION_MIN_FRAMES or (n - MOTION_MIN_FRAMES) % MOTION_EVERY:
            return
        fit = MotionFit(self._clip)
        found = [[T, fit.score(T)] for T, _ in self._hypotheses] + [list(h) for h in motion_starts(fit, MAX_HYPOTHESES,
                                                                                                    seed=self.frame)]
        self._hypotheses = sorted(found, key=lambda h: -h[1])[:MAX_HYPOTHESES]

    def _settled(self, T_new: np.ndarray, T_base_ee: np.ndarray, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray,
                 found: FrameCandidates, timings: dict) -> tuple[np.ndarray, Segmentation]:
        """RGB only: a first calibration from the motion lies centimetres off, mostly along the optical axis,
        which one view's outline barely fixes. The frames seen before join the memory, segmented at it, and the
        calibration is refined over them and this frame, the frames segmented again, until the robot moves less
        than a pixel (at most RGB_START_ROUNDS times), not over the next frames."""
        t0 = time.perf_counter()
        self._remember_waiting(T_new)
        timings["segmentation"] += 1e3 * (time.perf_counter() - t0)
        seen = found.segmentation
        for _ in range(RGB_START_ROUNDS):
            self.T_cam_base, self._fitted = T_new, None  # refined over the key frames, not judged to stand
            self._refresh_key_frames(T_new)
            T, T_new = T_new, self._refined(T_new, T_base_ee, found, timings)
            seen = self._segment_again(T_new, rgb, depth, K, found, timings)
            if self.parts.motion_px(placed(T, found.parts), placed(T_new, found.parts), K) < 1.0:
                break
        return T_new, seen

    def _remember_waiting(self, T_cam_base: np.ndarray) -> None:
        """RGB only: the frames seen before the motion gave any hypothesis join the memory once one is accepted,
        segmented at it (no template path: the outline is what the refinement fits), as later frames do."""
        for frame, rgb, K, T_base_ee, T_base_parts in self._waiting:
            no_depth = np.zeros(rgb.shape[:2])
            seen = segment(self.parts.coarse, T_cam_base, T_base_parts, rgb, no_depth, K, self.colour, self._band_px,
                           self._depth_sigma, cover=True)
            found = FrameCandidates(np.eye(3), [], 0, {}, segmentation=seen, parts=T_base_parts,
                                    silhouette=mask_view(seen.robot, K, no_depth))
            self.pool.consider(MemoryEntry(frame, T_base_ee, found), need_candidates=False)
        self._waiting = []

    def _explains(self, T_cam_base: np.ndarray, T_base_parts: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
                  K: np.ndarray, seen: Segmentation, has_depth: bool) -> str:
        """How well a first calibration explains the frame (with depth: SURE, PASSES or FAILS) or, RGB only,
        the motion so far and the frame's colours across its outline (SURE or FAILS)."""
        if has_depth:
            return _explains_frame(self.parts, T_cam_base, T_base_parts, rgb, depth, K, seen.view)
        explains = (bool(self._hypotheses) and outline_contrast(seen.view.inside > 0, rgb) >= RGB_CONTRAST
                    and MotionFit(self._clip).score(T_cam_base) >= MOTION_KEPT * self._hypotheses[0][1])
        return SURE if explains else FAILS

    def _drop(self) -> None:
        """RGB only: an accepted calibration under which the colour no longer changes across ACCEPT_CONTRAST of the
        robot's outline is dropped, with what was learned from it (the colours, the last fit) and the motion
        search's hypotheses; the search runs again every MOTION_EVERY frames, and the frames until another
        calibration is accepted are no-estimates."""
        self.T_cam_base, self._fitted, self._passing = None, None, None
        self.colour = ColourModel()
        self._hypotheses = []

    def _start(self, T_base_parts: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
               K: np.ndarray) -> np.ndarray | None:
        """What this frame refines: the calibration accepted, else the start kept from the last frame (it goes on
        being refined as frames arrive) unless the best hypothesis scores higher on this frame
        (`_depth_score`), else the best hypothesis. Seed 103 scene 7's near pass at frame 0 kept a UR5e 68 cm off
        on a sliver of the image (4.3 %, agreement 0.99, contrast 0.84), which failed at frame 1 while a hypothesis
        0.8 cm off, covering 13 %, ranked first; the hypothesis it came from is no guide (seed 59 scene 8: a start
        kept from one 27 cm off was refined to 0.7 cm over four frames as that one dropped out of the ranking)."""
        if self.T_cam_base is not None:
            return self.T_cam_base
        best = self._hypotheses[0][0] if self._hypotheses else None
        if self._passing is None or best is None:
            return best if self._passing is None else self._passing
        kept, other = (_depth_score(self.parts, T, T_base_parts, rgb, depth, K) for T in (self._passing, best))
        return self._passing if kept >= other else best

    def _accepts(self, verdict: str, T_start: np.ndarray, T_new: np.ndarray, T_base_parts: np.ndarray,
                 rgb: np.ndarray, depth: np.ndarray, K: np.ndarray) -> bool:
        """Whether the first calibration T_new, refined from T_start on this frame, is taken: SURE from a
        hypothesis, or passing from the start kept from the last frame, which this frame bears out. A start that
        passes and is not taken is kept for the next frame."""
        kept, self._passing = (self._passing if T_start is self._passing else None), None
        if verdict == FAILS:
            return False
        if verdict == SURE and kept is None:
            return True
        if kept is not None and (_depth_score(self.parts, T_start, T_base_parts, rgb, depth, K)
                                 >= KEPT_SCORE * _depth_score(self.parts, T_new, T_base_parts, rgb, depth, K)):
            return True
        self._passing = T_new
        return False

    def _refresh_key_frames(self, T: np.ndarray) -> None:
        """Key frames segmented at a calibration that has since moved them by more than a pixel are
        segmented again at this one (their masks came from the model as it stood)."""
        for entry in self.pool.entries:
            seen = entry.found.segmentation
            if seen is None:
                continue
            K = entry.found.silhouette.K
            if self.parts.motion_px(placed(seen.T_cam_base, entry.found.parts), placed(T, entry.found.parts), K) > 1.0:
                again = segment(self.parts.coarse, T, entry.found.parts, seen.rgb, seen.depth, K, self.colour,
                                BAND_MIN_PX, self._depth_sigma, robot_mask=seen.robot_mask, ee_mask=seen.ee_mask,
                                cover=seen.cover, sensor=seen.sensor_depth, regions=seen.cover)
                entry.found.segmentation, entry.found.silhouette = again, mask_view(again.robot, K, seen.depth)
                if entry.found.surface is not None:
                    entry.found.cloud = _robot_cloud(again, K, self.opts.depth_window_px)

    def _estimate(self, found: FrameCandidates, T_base_ee: np.ndarray, timings: dict,
                  prior: np.ndarray | None = None):
        """`prior`: a calibration to refine when no template candidate is found (no mask given)."""
        opts, cands = self.opts, found.candidates
        if opts.variant == "A":
            if not cands:
                return None, 0.0, 0
            best = max(cands, key=lambda c: c.n_inliers)
            return best.T_cam_ee @ inv_T(T_base_ee), float(best.n_inliers), 0
        views = self._with_key_frames(T_base_ee, found, opts.k_f if opts.variant in ("C", "D") else 0)
        frames = [(T, f.K, f.candidates) for T, f in views]
        # the estimator's own segmentation (no mask, or masks as a prior) and a calibration standing: the template
        # path no longer runs (`_step_unmasked`), and its key frames' candidates are not solved again either; the
        # refinement starts from the calibration
        if not any(c for _, _, c in frames) or (prior is not None and self.T_cam_base is not None):
            if prior is None:
                return None, 0.0, 0
            return self._refined(prior, T_base_ee, found, timings), 0.0, len(frames) - 1
        if opts.variant == "D":
            keep, T_init = consensus([(T, c) for T, _, c in frames], opts.symmetry_tolerance_deg)
            frames = [(T, Kc, [c for c, k in zip(cs, ks) if k]) for (T, Kc, cs), ks in zip(frames, keep)]
        elif opts.variant == "C" and self.T_cam_base is not None:
            T_init = self.T_cam_base
        else:
            T_init = _init_from(frames)
        obs = stack(frames)
        T, _ = optimize(T_init, obs, opts.optimize)
        if opts.icp:
            T = self._align_depth(T, obs, [(T_b, f.cloud) for T_b, f in views])
        if opts.refine != "none":
            T = self._refined(T, T_base_ee, found, timings)
        score = float(np.sum(reprojection_px(T, stack(frames[:1])) <= opts.single.pnp_threshold_px))
        return T, score, len(frames) - 1

    def _refined(self, T: np.ndarray, T_base_ee: np.ndarray, found: FrameCandidates, timings: dict,
                 others: bool = True, fine: bool = False) -> np.ndarray:
        """The silhouette refinement over the current frame and its own key frames, from T and (`others`) the other
        starts; `fine`: at the finest scale only."""
        opts = self.opts
        t0 = time.perf_counter()
        k = opts.silhouette_key_frames if opts.variant in ("C", "D") else 0  # its own key frames, not D's
        fitted = self._with_key_frames(T_base_ee, found, k)
        clouds, models = self._depth_frames(fitted) if opts.depth_in_refinement else ([], self.model)
        starts = self._starts(T, T_base_ee, found) if others else [T]
        T = self._refine_silhouette(starts, [(f.parts, f.silhouette) for _, f in fitted], clouds, models, fine)
        timings["refinement"] = timings.get("refinement", 0.0) + 1e3 * (time.perf_counter() - t0)
        return T

    def _depth_frames(self, fitted: list) -> tuple[list, SurfaceModel | list[SurfaceModel]]:
        """The frames' depth points, each (T_base_model, cloud), and what they show: the end-effector's model,
        or each frame's own (`FrameCandidates.surface`, already in the base frame)."""
        if all(f.surface is None for _, f in fitted):
            return [(T_b, f.cloud) for T_b, f in fitted], self.model
        return [(np.eye(4), f.cloud) for _, f in fitted], [f.surface for _, f in fitted]

    def _with_key_frames(self, T_base_ee: np.ndarray, found: FrameCandidates, k: int) -> list:
        """The current frame, then k key frames of the memory: (T_base_ee, FrameCandidates) each. With no mask
        and no calibration accepted yet, the current frame alone: acceptance judges the current frame only, and
        refining a hypothesis over the memory cost a failing segment more with every frame (seed-11 stereo scene
        15: 3.7 s at frame 0, 13 s at frame 5)."""
        if found.segmentation is not None and self.T_cam_base is None:
            k = 0
        return [(T_base_ee, found)] + [(e.T_base_ee, e.found) for e in self.pool.key_frames(T_base_ee[:3, :3], k)]

    def _align_depth(self, T: np.ndarray, obs, clouds: list) -> np.ndarray:
        """Alternate nearest-point association and the joint optimisation with the point-to-plane term."""
        opts = self.opts
        for _ in range(opts.icp_iterations):
            planes = associate(T, clouds, self.model, opts.icp_gate_m)
            T_new, _ = optimize(T, obs, opts.optimize, [PlaneTerm(planes, opts.icp_sigma_m)])
            moved = np.linalg.norm(T_new[:3, 3] - T[:3, 3])
            T = T_new
            if moved < ICP_MOVED_M:
                break
        return T

    def _starts(self, T: np.ndarray, T_base_ee: np.ndarray, found: FrameCandidates) -> list[np.ndarray]:
        """The optimised calibration, the current frame's best candidates' (most inliers first, symmetry
        disambiguation notwithstanding: the masks judge them), those the end-effector's positions so far
        imply (feepe/centres.py) and, in a segment's first frames, those of the robot's depth
        (feepe/robot_starts.py)."""
        best = sorted(found.candidates, key=lambda c: -c.n_inliers)[:self.opts.silhouette_starts]
        return ([T] + [c.T_cam_ee @ inv_T(T_base_ee) for c in best] + self.centres.starts()
                + found.robot_starts)

    def _robot_starts(self, T_base_parts: np.ndarray, robot_mask: np.ndarray, depth: np.ndarray,
                      mask: np.ndarray, K: np.ndarray) -> list[np.ndarray]:
        pivot_cam = observed_centre(depth, mask, K)
        if pivot_cam is None:
            return []
        model_base, _ = self._robot_samples.placed(T_base_parts)
        pivot_base = transform_points(T_base_parts[0], self.silhouette.centre[None])[0]
        return robot_starts(model_base, observed_points(depth, robot_mask, K), pivot_base, pivot_cam)

    def _refine_silhouette(self, starts: list[np.ndarray], frames: list, clouds: list, models,
                           fine: bool = False) -> np.ndarray:
        """Online: with no new key frame since the last refinement (or fewer than `silhouette_refit_growth`
        of the memory's size then) and a current mask that the last calibration explains as well as it
        explained the key frames, it stands. Else it is refined at the
        finest scale and kept unless another start explains the current mask clearly better; then every start
        is scored on all key frames and the best ones are refined coarse to fine. The best mean mask IoU wins;
        with depth, the best IoU times the depth's agreement (`feepe.icp.depth_agreement`) at the noise scale
        measured at the best IoU's pose (so exact depth judges sharply, a stereo camera's loosely)."""
        opts, sigmas, current = self.opts, self.opts.silhouette_sigmas_px, frames[:1]
        if fine:
            sigmas = sigmas[-1:]

        def fit(T: np.ndarray, views: list) -> float:
            return mean_iou(self.parts, T, views, IOU_STRIDE)

        warm = None
        if self.T_cam_base is not None:
            last = self._fitted
            if last is not None and len(self.pool) < max(last.pool_size + 1,
                                                          last.pool_size * (1 + opts.silhouette_refit_growth)):
                if last.iou is None:
                    last.iou = fit(last.T_cam_base, last.frames)
                if fit(self.T_cam_base, current) >= last.iou - opts.silhouette_switch_iou:
                    return self.T_cam_base  # the memory grew too little, and the current mask agrees as they did
            warm = self._descend(self.T_cam_base, frames, sigmas[-1:], clouds, models)
            # what another start must beat; an IoU exceeds neither 1 nor its bound, so few starts need a render
            bar = fit(warm, current) + opts.silhouette_switch_iou
            T_base_parts, mv = current[0]
            if bar >= 1.0 or all(iou_bound(self.parts, placed(T, T_base_parts), mv, IOU_STRIDE) <= bar
                                 or fit(T, current) <= bar for T in starts):
                self._fitted = _Fitted(len(self.pool), warm, frames)
                return warm
        scored = sorted(((fit(T, frames), i) for i, T in enumerate(starts)), reverse=True)
        chosen = [starts[i] for _, i in scored[:opts.silhouette_starts]]
        if self._own_masks and clouds and len(chosen) > 1 and len(sigmas) > 1:
            # the estimator's own masks: every start descends the coarsest stage, the best of them (`_best`) the
            # others, and only its descent is judged against depth (`_descend`): a first frame descended three starts
            # to the finest scale (seed 131's first frames 1064 -> 935 ms; with the PPF's votes and the colour
            # rounds' finest scale, seeds 131 and 137 ADD 93.14 and 85.16 against 93.20 and 85.15). RGB only, every
            # start descends every scale (thinned, data/mini's six segments 41.05/45.82 -> 38.24/42.89)
            coarse = [self._descend(T, frames, sigmas[:1], clouds, models, judged=False) for T in chosen]
            chosen, sigmas = [coarse[self._best(coarse, frames, clouds, models)[0]]], sigmas[1:]
        descended = ([warm] if warm is not None else []) + [self._descend(T, frames, sigmas, clouds, models)
                                                           for T in chosen]
        best, ious = self._best(descended, frames, clouds, models)
        self._fitted = _Fitted(len(self.pool), descended[best], frames, ious[best])
        return descended[best]

    def _best(self, descended: list[np.ndarray], frames: list, clouds: list, models) -> tuple[int, list[float]]:
        """Which calibration explains the frames best, and each one's mean mask IoU: the best IoU or, with depth,
        the best IoU times the depth's agreement, all at the best IoU's noise scale."""
        opts = self.opts
        ious = [mean_iou(self.parts, T, frames, IOU_STRIDE) for T in descended]
        scores = ious
        if clouds:
            distances = [depth_distances(T, clouds, models, opts.depth_sigma_m, opts.depth_sigma_z2)
                         for T in descended]
            scale = robust_scale(distances[int(np.argmax(ious))])
            scores = [iou * (a if np.isfinite(a) else 1.0)
                      for iou, a in zip(ious, (depth_agreement(d, scale) for d in distances))]
        return int(np.argmax(scores)), ious

    def _descend(self, T: np.ndarray, frames: list, sigmas, clouds: list, models, judged: bool = True) -> np.ndarray:
        """Gauss-Newton on the contour term (and depth), the contour re-extracted between solves (as ICP
        re-associates). Depth may move the pose only within the masks' own uncertainty: when the result's
        mean contour distance exceeds the masks-only pose's by more than `silhouette_depth_tolerance`
        standard errors, a biased sensor is pulling it off the masks, and the masks-only pose is returned.
        With the estimator's own masks (read off the same depth) this is judged only until a calibration is
        accepted: then it keeps a start that depth pulls off from being taken (seed 103's UR5e + 2F-85: ADD 87.15
        -> 0 without it); once one stands it fired 0 of 489 times on four runs and cost 8 % of a frame
        (issue 34). `judged`: False for a stage that only ranks starts (`_refine_silhouette`)."""
        lost_px = min(MIN_SPAN_PX, self._span_px(T, frames[0]) / 2)
        T = self._solve(T, frames, sigmas, clouds, models, lost_px)
        judged = judged and not self._tracking
        if clouds and judged and self._span_px(T, frames[0]) >= lost_px:
            T_masks = self._solve(T, frames, sigmas[-1:], [], models, lost_px)
            (with_depth, _), (masks, error) = (contour_fit(self.parts, X, frames) for X in (T, T_masks))
            if with_depth > masks + self.opts.silhouette_depth_tolerance * error:
                return T_masks
        return T

    def _solve(self, T: np.ndarray, frames: list, sigmas, clouds: list, models, lost_px: float) -> np.ndarray:
        """`lost_px`: the descent has run off once it draws the model smaller than this (`_span_px`), where its
        outline can no longer pull it back; it stops there."""
        no_matches = stack([])
        opts = self.opts
        inner = OptimizeOptions(max_iterations=SOLVE_ITERATIONS, min_decrease=MIN_DECREASE, min_step=MIN_STEP)
        round_moved_m = WARM_ROUND_MOVED_M if self._tracking else ROUND_MOVED_M
        for k, sigma in enumerate(sigmas):
            # each frame's mask weighs by how well it fits (beside depth at every stage, else at the finest):
            # a segmenter's few-pixel errors then yield the range to depth and to the better masks, exact masks
            # keep it (beside depth at the finest stage down to min_sigma)
            finest = k == len(sigmas) - 1
            floor = sigma
            if clouds and finest:
                floor = max(opts.silhouette_min_sigma_px, OWN_MASKS_MIN_SIGMA_PX if self._own_masks else 0.0)
            for _ in range(opts.silhouette_rounds):
                if self._span_px(T, frames[0]) < lost_px:
                    return T
                model = self.parts if finest else self.parts.coarse  # exact at the finest stage
                terms = [contour_term(model, T, frames, floor, step_px=max(1.0, sigma / 2),
                                      measured=bool(clouds) or finest)]
                if clouds:
                    planes = depth_planes(T, [mv for _, mv in frames], clouds, models, opts.icp_gate_m)
                    terms.append(sensor_plane_term(planes, T, opts.depth_sigma_m, opts.depth_sigma_z2))
                T_new, _ = optimize(T, no_matches, inner, terms=terms)
                moved = np.linalg.norm(T_new[:3, 3] - T[:3, 3])
                T = T_new
                if moved < round_moved_m:
                    break
        return T

    @property
    def _tracking(self) -> bool:
        """Whether a calibration stands and the refinement fits the estimator's own masks: each frame then goes on
        from the last, and depth is no longer judged against those masks (read off the same depth)."""
        return self._own_masks and self.T_cam_base is not None

    def _span_px(self, T: np.ndarray, frame: tuple) -> float:
        """A bound on the model's image extent in the frame at calibration T (`PartsSilhouette.span_px`)."""
        T_base_parts, mv = frame
        return self.parts.span_px(placed(T, T_base_parts), mv.K)


def _init_from(frames) -> np.ndarray:
    """The calibration implied by the candidate with the most inliers among the frames."""
    T_base_ee, _, c = max(((T, K, c) for T, K, cs in frames for c in cs), key=lambda f: f[2].n_inliers)
    return c.T_cam_ee @ inv_T(T_base_ee)


def _check_robot(robot: RobotView | None, shape: tuple, n_links: int, masked: bool = True) -> RobotView:
    """`masked`: the robot's mask is given (the robot's outline); else only the links' poses are read."""
    if n_links == 0:
        raise UserError("silhouette 'robot' needs the arm's link meshes: reset(arm=[SilhouetteModel(...), ...])")
    if robot is None:
        raise UserError("silhouette 'robot' needs each frame's robot view: step(..., robot=RobotView(mask, T_base_links))")
    T = np.asarray(robot.T_base_links, float)
    if T.shape != (n_links, 4, 4):
        raise UserError(f"T_base_links is {T.shape}, expected ({n_links}, 4, 4): one pose per arm link given to reset(arm=...)")
    if not masked:
        return RobotView(None, T)
    if robot.mask is None:
        raise UserError("the robot's outline fits its mask: step(..., robot=RobotView(mask, T_base_links)); with no "
                        "end-effector mask either, pass mask=None and the estimator segments the robot itself")
    mask = np.asarray(robot.mask, bool)
    if mask.shape != tuple(shape):
        raise UserError(f"the robot mask is {mask.shape}, the end-effector mask {tuple(shape)}; pass both for the RGB image")
    return RobotView(mask, T)


def _check_inputs(rgb, depth, mask, K, T_base_ee) -> None:
    rgb, depth = np.asarray(rgb), np.asarray(depth)
    mask = np.zeros(rgb.shape[:2], bool) if mask is None and rgb.ndim == 3 else np.asarray(mask)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise UserError(f"rgb must be (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
    if depth.shape != rgb.shape[:2] or mask.shape != rgb.shape[:2]:
        raise UserError(f"image sizes differ: rgb {rgb.shape[:2]}, depth {depth.shape}, mask {mask.shape}; "
                        "pass the depth and mask registered to the RGB image")
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise UserError(f"K must be a 3x3 intrinsics matrix with positive focal lengths, got {K.tolist()}")
    h, w = rgb.shape[:2]
    if not (-0.5 * w <= K[0, 2] <= 1.5 * w and -0.5 * h <= K[1, 2] <= 1.5 * h):
        raise UserError(f"K's principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) does not fit a {w}x{h} image; "
                        "is K for another resolution?")
    if np.shape(T_base_ee) != (4, 4):
        raise UserError(f"T_base_ee must be 4x4, got {np.shape(T_base_ee)}")


def _robot_cloud(seen: Segmentation, K: np.ndarray, window_px: float) -> np.ndarray:
    """The depth points of the robot as the estimator segmented it, for the refinement with depth; a sensor's
    depth (rough, unlike rendered exact depth) less its matching window's bias at the model's surface as the
    segmentation placed it (the stereo camera's depth of the robot's rounded links reads farther)."""
    depth = seen.depth
    if window_px > 0 and seen.sensor_depth:
        depth = without_window_bias(depth, seen.view.depth, seen.view.inside > 0, window_px)
    return observed_cloud(depth, seen.robot, K, ROBOT_DEPTH_POINTS)


def _coarse_depth_fit(parts: PartsSilhouette, T_cam_base: np.ndarray, T_base_parts: np.ndarray, depth: np.ndarray,
                      K: np.ndarray) -> tuple[DepthFit, np.ndarray]:
    """How the frame's depth meets the robot's (coarse meshes) placed at the calibration, on every
    IOU_STRIDE-th pixel, and that rendered depth."""
    coarse, grid = strided(depth, K, IOU_STRIDE)
    rendered = parts.coarse.render_depth(placed(T_cam_base, T_base_parts), grid, coarse.shape)
    return depth_fit(rendered, coarse), rendered


def _coarse_colours(rgb: np.ndarray, K: np.ndarray) -> np.ndarray:
    """The frame's colours on the coarse grid as outlines are judged on them (registration.contrast_image)."""
    return contrast_image(strided(rgb, K, IOU_STRIDE)[0])


def _coarse_judgement(parts: PartsSilhouette, T_cam_base: np.ndarray, T_base_parts: np.ndarray, colours: np.ndarray,
                      depth: np.ndarray, K: np.ndarray) -> tuple[float, str]:
    """A hypothesis judged on the coarse grid, as it stands: its depth score (`_depth_score`) and its verdict
    (`_explains_frame`), from one render and one contrast on the coarse meshes' outline (`colours`: the frame's
    `_coarse_colours`)."""
    fit, rendered = _coarse_depth_fit(parts, T_cam_base, T_base_parts, depth, K)
    contrast = contrast_along(rendered > 0, colours, fit.front)
    return fit.score(contrast), _verdict(fit, rendered.size, contrast)


def _depth_score(parts: PartsSilhouette, T_cam_base: np.ndarray, T_base_parts: np.ndarray, rgb: np.ndarray,
                 depth: np.ndarray, K: np.ndarray) -> float:
    """A calibration's depth fit to the frame (coarse grid), its agreement borne out by the colour across its
    outline: how hypotheses are scored and ranked (registration.DepthFit.score)."""
    return _coarse_judgement(parts, T_cam_base, T_base_parts, _coarse_colours(rgb, K), depth, K)[0]


def _explains_frame(parts: PartsSilhouette, T_cam_base: np.ndarray, T_base_parts: np.ndarray, rgb: np.ndarray,
                    depth: np.ndarray, K: np.ndarray, view: ModelView) -> str:
    """Whether the robot placed at the calibration (`view`: as the frame's segmentation drew it) explains the frame
    well enough to be a first estimate (no mask given; `_verdict`), its depth judged on the coarse grid, the colour
    across its outline where nothing nearer hides it (`registration.hidden`)."""
    found, rendered = _coarse_depth_fit(parts, T_cam_base, T_base_parts, depth, K)
    drawn = view.inside > 0
    return _verdict(found, rendered.size, outline_contrast(drawn, rgb, hidden(np.where(drawn, view.depth, 0.0), depth)))


def _verdict(found: DepthFit, n_pixels: int, contrast: float) -> str:
    """A calibration's verdict from its depth fit (on a grid of `n_pixels`) and its outline's contrast: enough of
    it in view, nothing nearer hides most of its pixels with depth, most of those agree, few are seen through, and
    the image's colour changes across most of its outline (PASSES); SURE when the agreement, the seen-through
    share and the contrast clear the higher bars."""
    unhidden = found.drawn - found.in_front
    in_view = found.drawn >= ACCEPT_MIN_SHARE * n_pixels and unhidden >= ACCEPT_UNHIDDEN * found.drawn
    if not (in_view and found.agree >= ACCEPT_AGREE * unhidden
            and found.seen_through <= ACCEPT_SEEN_THROUGH * found.drawn and contrast >= ACCEPT_CONTRAST):
        return FAILS
    sure = (found.agree >= SURE_AGREE * unhidden and found.seen_through <= SURE_SEEN_THROUGH * found.drawn
            and contrast >= SURE_CONTRAST)
    return SURE if sure else PASSES
