"""FEEPE speed: onboarding time per end-effector and per-stage ms/frame (variant D) on a rendered data set.

Prints figures, asserts nothing: `make bench` or `.venv/bin/python benchmarks/estimator.py [--dataset data/mini]
[--backbone sift+normals] [--frames N] [--refine silhouette|silhouette+depth] [--silhouette robot] [--masks
none] [--scenes 0,3] [--profile FILE] [--cache-dir DIR]`. Onboarding runs into a fresh cache folder, so it is
timed cold, unless --cache-dir names one. With --refine, the refinement's own ms/frame (our extension) is the `refinement` stage. `--masks none`: no mask of any kind (our extension, issue
34): the estimator finds the robot (`registration`) and segments it (`segmentation`) itself, and fits the
robot's outline with depth, as `eval.run --masks none` runs it.
"""

import argparse
import cProfile
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
    parser.add_argument("--scenes", help="comma-separated scene ids (default: all)")
    parser.add_argument("--profile", type=Path, help="write cProfile's statistics of the frames here")
    parser.add_argument("--cache-dir", type=Path, help="onboarding cache (default: a fresh one, timed cold)")
    args = parser.parse_args()
    scenes = None if args.scenes is None else {int(s) for s in args.scenes.split(",")}
    profile = cProfile.Profile() if args.profile else None
    given = args.masks == "given"
    dataset = Dataset(Path(args.dataset))
    net = get_backbone(args.backbone)
    timings, banks = [], {}
    with tempfile.TemporaryDirectory() as fresh:
        cache = args.cache_dir or Path(fresh)
        for scene in dataset.scenes():
            if scenes is not None and scene.scene_id not in scenes:
                continue
            meta = scene.meta
            ee = meta.end_effector
            if ee not in banks:
                folder = find_template_set(args.templates_dir or dataset.templates_dir, ee, None)
                banks[ee] = onboard(folder, net, cache_dir=cache)
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
                if profile:
                    profile.enable()
                found = est.step(f.rgb, f.depth, f.mask_visib if given else None, f.K, f.T_base_ee, view)
                if profile:
                    profile.disable()
                timings.append((im_id == scene.im_ids[0], found.timings))
    if profile:
        profile.dump_stats(args.profile)
    print(f"{args.backbone}, variant D, refine {opts.refine} ({opts.silhouette}), masks {args.masks}, {len(timings)} frames of "
          f"{dataset.root}:")
    # a segment's first frame (the no-mask path's registration) costs many later ones: both shown apart
    for label, rows in (("all frames", [t for _, t in timings]), ("first frames", [t for first, t in timings if first]),
                        ("later frames", [t for first, t in timings if not first])):
        if not rows:
            continue
        mean = {s: float(np.mean([t.get(s, 0.0) for t in rows])) for s in STAGES}
        non_backbone = mean["total"] - mean["backbone"]
        print(f"  {label} ({len(rows)}): " + ", ".join(f"{s} {mean[s]:.1f}" for s in STAGES)
              + f" ms/frame; everything but the backbone {non_backbone:.1f} ms/frame")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"benchmark wall time {time.perf_counter() - t0:.0f} s")
