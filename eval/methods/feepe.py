"""`feepe`: the FEEPE estimator run online over each segment, with the data set's own templates.

Templates come from `<dataset>/templates/<ee>_<views>x<inplane>_<res>px/` (python -m syneepose templates)
or from `--templates-dir`; `--n-templates` picks a set by count when several were rendered (default: the
largest count, then the largest resolution). `--icp` adds our depth-alignment extension, which reads the
end-effector model from `<dataset>/models/`. `--silhouette robot` has the refinement fit the whole robot's
mask: the arm links' meshes come from the robot assets (the URDF the data set was rendered from) and their
poses from forward kinematics of each frame's joint positions, as a user with the robot's URDF has them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from eval.methods import option, register
from eval.methods.base import Estimate, Observation
from feepe.backbones import DEFAULT as DEFAULT_BACKBONE
from feepe.backbones import get_backbone
from feepe.candidates import SingleFrameOptions
from feepe.estimator import (GIVEN_MASKS, REFINEMENTS, SILHOUETTES, VARIANTS, Estimator, FeepeOptions, RobotView,
                             describe, fitting_own_masks, load_models)
from feepe.onboarding import onboard
from feepe.silhouette import SilhouetteModel
from kernel.bop import SceneMeta
from kernel.dataset import TEMPLATES, Dataset
from kernel.errors import UserError
from kernel.template_set import find_template_set


@dataclass(frozen=True)
class FeepeFlags:
    """What a user sets of FEEPE; everything else keeps FeepeOptions' defaults (the paper's setup)."""

    variant: str = option("D", "ablation variant", choices=VARIANTS)
    backbone: str = option(DEFAULT_BACKBONE, "feature backbone")
    icp: bool = option(False, "add depth alignment (our extension, not in the paper)")
    refine: str = option("none", "refine the calibration on the key frames' masks, alone or with depth over a sensor "
                         "noise model (our extension, not in the paper)", choices=REFINEMENTS)
    silhouette: str = option("ee", "the outline --refine fits: the end-effector's mask (ee, the paper's input) or "
                             "the whole robot's (robot: every arm link by FK; needs robot_mask_visib/ in the data "
                             "set)", choices=SILHOUETTES)
    given_masks: str = option("truth", "masks handed in: taken as they are (truth) or weighed against FEEPE's own "
                              "segmentation of the robot, as one more signal of it (prior; fits the robot's outline; "
                              "our extension)", choices=GIVEN_MASKS)
    refit_growth: float = option(0.0, "a new key frame refits the calibration only once the memory grew by this "
                                 "fraction since the last refit (0: each new key frame; our extension)")
    layer: int | None = option(None, "DINOv2 block, counted from 0 as FoundPose (paper: 19 of ViT-L's 0..23)",
                               within=(0, 10000))
    n_templates: int | None = option(None, "template set by count (default: largest)", within=(1, 10000))
    k_r: int = option(5, "reference templates per frame (paper: 5)", within=(1, 10000))
    k_f: int = option(8, "key frames (paper: 8)", within=(0, 10000))
    backbone_weights: str | None = option(None, "DINOv2 weights (HF folder or torch-hub .pth)")
    templates_dir: str | None = option(None, f"template root (default: DATASET/{TEMPLATES})")
    bow_assignment: str = option("foundpose", "BoW word assignment: foundpose (FoundPose's) or gaussian (ours: "
                                 "distance-weighted votes)", choices=("foundpose", "gaussian"))


@register("feepe")
class Feepe:
    Options = FeepeFlags

    def __init__(self, flags: FeepeFlags):
        own = flags.given_masks == "prior"  # its own segmentation: the robot's outline, the refinement on
        self.opts = FeepeOptions(variant=flags.variant, k_f=flags.k_f, icp=flags.icp,
                                 refine="silhouette" if own and flags.refine == "none" else flags.refine,
                                 silhouette="robot" if own else flags.silhouette,
                                 silhouette_refit_growth=flags.refit_growth,
                                 given_masks=flags.given_masks,
                                 single=SingleFrameOptions(k_r=flags.k_r))
        self.bow_assignment = flags.bow_assignment
        self._refine_chosen = flags.refine != "none"
        kwargs = {}
        if flags.backbone.startswith("dinov2"):
            kwargs = {"layer": flags.layer, "weights": flags.backbone_weights}
        elif flags.layer is not None or flags.backbone_weights is not None:
            raise UserError(f"--layer and --backbone-weights are DINOv2 options; backbone {flags.backbone!r} has "
                            "neither")
        self.backbone = get_backbone(flags.backbone, **kwargs)
        self.n_templates, self.templates_dir = flags.n_templates, flags.templates_dir
        self._estimators: dict[str, Estimator] = {}
        self._current: Estimator | None = None
        self._arms: dict[str, tuple] = {}  # config -> (Robot, arm link names, their silhouette models)
        self._arm = None

    def options(self) -> dict:
        """The table keys first (variant, backbone, layer, n_templates, k_r, k_f), then every detail."""
        refine = {"refine": self.opts.refine} if self.opts.refine != "none" else {}  # absent: old runs resume
        if self.opts.silhouette != "ee":
            refine["silhouette"] = self.opts.silhouette
        if self.opts.silhouette_refit_growth:
            refine["refit_growth"] = self.opts.silhouette_refit_growth
        if self.opts.given_masks != "truth":
            refine["given_masks"] = self.opts.given_masks
        return {"variant": self.opts.variant, "icp": self.opts.icp, **refine, "backbone": self.backbone.name,
                "layer": self.backbone.options().get("layer"), "n_templates": self.n_templates,
                "k_r": self.opts.single.k_r, "k_f": self.opts.k_f, "bow_assignment": self.bow_assignment,
                "estimator": describe(self.opts, self.backbone)}

    def given(self, masks: bool, depth: bool) -> None:
        """With no mask given the estimator finds and segments the robot itself, as with `--given-masks
        prior`, and fits the robot's outline to it (the arm's meshes from the URDF; feepe.estimator's
        fitting_own_masks)."""
        if masks and self.opts.given_masks == "truth":
            return
        self.opts = fitting_own_masks(self.opts, depth, self._refine_chosen)

    def inputs(self, meta: SceneMeta, scene_dir: Path) -> list[Path]:
        """The template set of the scene's end-effector, the model `--icp` / `--refine` align, and for the
        robot's outline the arm's URDF and link meshes."""
        found = [self._templates(meta, scene_dir)]
        if self._needs_model:
            found.append(Dataset.of_scene(scene_dir).model_path(meta.obj_id))
        if self.opts.silhouette == "robot":
            robot, links, _ = self._arm_models(meta)
            found += [robot.urdf, *(path for name in links for path in link_mesh_paths(robot, name))]
        return found

    @property
    def _needs_model(self) -> bool:
        return self.opts.needs_surface or self.opts.refine != "none"  # the depth terms, the silhouette

    def _templates(self, meta: SceneMeta, scene_dir: Path) -> Path:
        root = Path(self.templates_dir) if self.templates_dir else Dataset.of_scene(scene_dir).templates_dir
        return find_template_set(root, meta.end_effector, self.n_templates)

    def start_scene(self, meta: SceneMeta, scene_dir: Path) -> None:
        ee = meta.end_effector
        if ee not in self._estimators:
            bank = onboard(self._templates(meta, scene_dir), self.backbone, self.opts.single.pad,
                           {"assignment": self.bow_assignment})
            model, silhouette = (load_models(Dataset.of_scene(scene_dir).model_path(meta.obj_id), self.opts)
                                 if self._needs_model else (None, None))
            self._estimators[ee] = Estimator(bank, self.backbone, self.opts, model, silhouette)
        self._current = self._estimators[ee]
        self._arm = self._arm_models(meta) if self.opts.silhouette == "robot" else None
        self._current.reset(arm=self._arm[2] if self._arm else None)

    def _arm_models(self, meta: SceneMeta) -> tuple:
        config = f"{meta.arm}+{meta.end_effector}"
        if config not in self._arms:
            self._arms[config] = arm_models(meta)
        return self._arms[config]

    def estimate(self, obs: Observation) -> Estimate:
        robot = None
        if self._arm is not None:
            if obs.robot_mask is None and obs.mask is not None and self.opts.given_masks == "truth":
                raise UserError(f"frame {obs.im_id}: --silhouette robot needs its robot mask (robot_mask_visib/)")
            robot = robot_view(self._arm, obs.robot_mask, obs.joint_positions)
        r = self._current.step(obs.rgb, obs.depth, obs.mask, obs.K, obs.T_base_ee, robot)
        return Estimate(T_cam_ee=r.T_cam_ee, score=r.score, time_s=r.timings["total"] / 1000.0,
                        T_cam_base=r.T_cam_base, extra={"timings_ms": r.timings, "n_key_frames": r.n_key_frames},
                        masks=r.masks if r.masks is not None or obs.mask is not None else {})


def arm_models(meta: SceneMeta) -> tuple:
    """(Robot, the arm links with a mesh, their silhouette models) for a scene rendered with robot masks."""
    from syneepose.robots.robot import load_robot

    robot = load_robot(f"{meta.arm}+{meta.end_effector}")
    # the parts of robot_mask_visib/ (the last is the end-effector, fitted by its BOP model); a scene rendered
    # before them has no robot mask, which only the outline with masks given needs
    links = meta.links[:-1] if meta.links else robot.arm_links
    return robot, links, [SilhouetteModel(link_mesh(robot, name)) for name in links]


def robot_view(arm: tuple, robot_mask: np.ndarray | None, joint_positions: np.ndarray) -> RobotView:
    """The robot mask and each arm link's pose in the base frame (FK of the joint positions)."""
    robot, links, _ = arm
    T_base_link = robot.T_base_link(joint_positions)
    return RobotView(robot_mask, np.stack([T_base_link[name] for name in links]))


def link_mesh_paths(robot, name: str) -> list[Path]:
    """The mesh files of one arm link's visuals, as its URDF names them."""
    return [robot.urdf.parent / visual.mesh for visual in robot.model.link(name).visuals]


def link_mesh(robot, name: str) -> trimesh.Trimesh:
    """One arm link's visual meshes in its link frame (metres); SilhouetteModel merges their corners."""
    parts = []
    for path, visual in zip(link_mesh_paths(robot, name), robot.model.link(name).visuals):
        parts.append(trimesh.load(str(path), force="mesh").apply_transform(visual.origin))
    return trimesh.util.concatenate(parts)
