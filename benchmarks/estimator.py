"""FEEPE speed: onboarding time per end-effector and per-stage ms/frame (variant D) on a rendered data set.

Prints figures, asserts nothing: `make bench` or `.venv/bin/python benchmarks/estimator.py [--dataset data/mini]
[--backbone sift+normals] [--frames N] [--refine silhouette|silhouette+depth] [--silhouette robot] [--masks
none]`. Onboarding runs into a fresh cache folder, so it is timed cold. With --refine, the refinement's own
ms/frame (our extension) is the `refinement` stage. `--masks none`: no mask of any kind (our extension, issue
34): the estimator finds the robot (`registration`) and segments it (`segmentation`) itself, and fits the
robot's outline with depth, as `eval.run --masks none` runs it.
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from eval.methods.feepe import arm_models, robot_view
from feepe.backbones import DEFAULT, get_backbone
from feepe.estimator import REFINEMENTS, Estimator, FeepeOptions, fitting_own_masks, load_models
from feepe.onboarding import onboard
from kernel.dataset import Dataset
from kernel.template_set import find_template_set

STAGES = ("registration", "segmentation", "backbone", "retrieval", "matching", "pnp", "optimisation", "refinement",
          "robot_starts", "total")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--dataset", default="data/mini")
    parser.add_argument("--backbone", default=DEFAULT)
    parser.add_argument("--frames", type=int, default=0, help="frames per scene (0: all)")
    parser.add_argument("--refine", default="none", choices=REFINEMENTS)
    parser.add_argument("--templates-dir", type=Path, help="template sets (default: DATASET/templates)")
    parser.add_argument("--silhouette", default="ee", choices=["ee", "robot"],
                        help="robot: the refinement fits the robot's outline (needs robot_mask_visib/)")
    parser.add_argument("--masks", default="given", choices=["given", "none"],
                        help="none: no mask of any kind; the refinement and outline are chosen as eval.run chooses them")
    args = parser.parse_args()
    given = args.masks == "given"
    dataset = Dataset(Path(args.dataset))
    net = get_backbone(args.backbone)
    timings, banks = [], {}
    with tempfile.TemporaryDirectory() as cache:
        for scene in dataset.scenes():
            meta = scene.meta
            ee = meta.end_effector
            if ee not in banks:
                folder = find_template_set(args.templates_dir or dataset.templates_dir, ee, None)
                banks[ee] = onboard(folder, net, cache_dir=Path(cache))
                print(f"onboarding {folder.name}: {banks[ee].seconds:.1f} s, {len(banks[ee].uv)} features")
            opts = FeepeOptions(variant="D", refine=args.refine, silhouette=args.silhouette)
            if not given:
                opts = fitting_own_masks(opts, depth=True, refine_chosen=args.refine != "none")
            est = Estimator(banks[ee], net, opts, *load_models(dataset.model_path(meta.obj_id), opts))
            arm = arm_models(meta) if opts.silhouette == "robot" else None
            est.reset(arm=arm[2] if arm else None)
            for im_id in scene.im_ids[: args.frames or None]:
                f = scene.frame(im_id)
                view = robot_view(arm, f.link_ids > 0 if given else None, f.joint_positions) if arm else None
                timings.append(est.step(f.rgb, f.depth, f.mask_visib if given else None, f.K, f.T_base_ee, view).timings)
    mean = {s: float(np.mean([t.get(s, 0.0) for t in timings])) for s in STAGES}
    non_backbone = mean["total"] - mean["backbone"]
    print(f"{args.backbone}, variant D, refine {opts.refine} ({opts.silhouette}), masks {args.masks}, {len(timings)} frames of "
          f"{dataset.root}: " + ", ".join(f"{s} {mean[s]:.1f}" for s in STAGES)
          + f" ms/frame; everything but the backbone {non_backbone:.1f} ms/frame")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"benchmark wall time {time.perf_counter() - t0:.0f} s")
