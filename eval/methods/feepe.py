"""`feepe`: the FEEPE estimator run online over each segment, with the data set's own templates.

Templates come from `<dataset>/templates/<ee>_<views>x<inplane>_<res>px/` (python -m syneepose templates)
or from `--templates-dir`; `--n-templates` picks a set by count when several were rendered (default: the
largest count, then the largest resolution). `--icp` adds our depth-alignment extension, which reads the
end-effector model from `<dataset>/models/`.
"""

from __future__ import annotations

from pathlib import Path

from eval.methods import register
from eval.methods.base import Estimate, Observation
from feepe.backbones import DEFAULT as DEFAULT_BACKBONE
from feepe.backbones import get_backbone
from feepe.candidates import SingleFrameOptions
from feepe.estimator import Estimator, FeepeOptions, describe, load_models
from feepe.onboarding import onboard
from syneepose.bop import SceneMeta
from syneepose.errors import UserError
from syneepose.templates import find_template_set

@register("feepe")
class Feepe:
    def __init__(self, variant: str = "D", backbone: str = DEFAULT_BACKBONE, layer: int | None = None,
                 n_templates: int | None = None, k_r: int = 5, k_f: int = 8, backbone_weights: str | None = None,
                 templates_dir: str | None = None, icp: bool = False, bow_assignment: str = "foundpose",
                 refine: str = "none"):
        if bow_assignment not in ("foundpose", "gaussian"):
            raise UserError(f"--bow-assignment {bow_assignment!r}: foundpose (FoundPose's) or gaussian (ours)")
        self.opts = FeepeOptions(variant=variant, k_f=k_f, icp=icp, refine=refine,
                                 single=SingleFrameOptions(k_r=k_r))
        self.bow_assignment = bow_assignment
        kwargs = {}
        if backbone.startswith("dinov2"):
            kwargs = {"layer": layer, "weights": backbone_weights}
        elif layer is not None or backbone_weights is not None:
            raise UserError(f"--layer and --backbone-weights are DINOv2 options; backbone {backbone!r} has neither")
        self.backbone = get_backbone(backbone, **kwargs)
        self.n_templates, self.templates_dir = n_templates, templates_dir
        self._estimators: dict[str, Estimator] = {}
        self._current: Estimator | None = None

    def options(self) -> dict:
        """The table keys first (variant, backbone, layer, n_templates, k_r, k_f), then every detail."""
        refine = {"refine": self.opts.refine} if self.opts.refine != "none" else {}  # absent: old runs resume
        return {"variant": self.opts.variant, "icp": self.opts.icp, **refine, "backbone": self.backbone.name,
                "layer": self.backbone.options().get("layer"), "n_templates": self.n_templates,
                "k_r": self.opts.single.k_r, "k_f": self.opts.k_f, "bow_assignment": self.bow_assignment,
                "estimator": describe(self.opts, self.backbone)}

    def inputs(self, meta: SceneMeta, scene_dir: Path) -> list[Path]:
        """The template set of the scene's end-effector, and the model `--icp` / `--refine` align."""
        root = Path(self.templates_dir) if self.templates_dir else Path(scene_dir).parents[1] / "templates"
        found = [find_template_set(root, meta.end_effector, self.n_templates)]
        if self.opts.needs_surface or self.opts.refine != "none":  # the depth terms, the silhouette
            found.append(Path(scene_dir).parents[1] / "models" / f"obj_{meta.obj_id:06d}.ply")
        return found

    def start_scene(self, meta: SceneMeta, scene_dir: Path) -> None:
        ee = meta.end_effector
        if ee not in self._estimators:
            folder, *model_ply = self.inputs(meta, scene_dir)
            bank = onboard(folder, self.backbone, self.opts.single.pad, {"assignment": self.bow_assignment})
            model, silhouette = load_models(model_ply[0], self.opts) if model_ply else (None, None)
            self._estimators[ee] = Estimator(bank, self.backbone, self.opts, model, silhouette)
        self._current = self._estimators[ee]
        self._current.reset()

    def estimate(self, obs: Observation) -> Estimate:
        r = self._current.step(obs.rgb, obs.depth, obs.mask, obs.K, obs.T_base_ee)
        return Estimate(T_cam_ee=r.T_cam_ee, score=r.score, time_s=r.timings["total"] / 1000.0,
                        T_cam_base=r.T_cam_base, extra={"timings_ms": r.timings, "n_key_frames": r.n_key_frames})
