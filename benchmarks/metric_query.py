"""How far the evaluator's default query (one vertex drawn per cell and frame, at most MAX_QUERY cells, every
vertex searched)
move a run's figures from BOP's exact mean over every vertex of models_eval/: the run's estimates
(results.csv) are scored both ways and the AUCs compared per end-effector, with the time each took.

Prints figures; asserts nothing. Run: `.venv/bin/python benchmarks/metric_query.py RESULT_DIR` (a folder
written by `python -m eval.run`).
"""

import argparse
import json
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from eval.bop_results import read_results
from eval.metrics import add, adds, auc
from eval.model_points import MAX_QUERY, load_eval_model
from kernel.bop import read_frame, read_scene
from kernel.dataset import Dataset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("run", help="result folder of python -m eval.run")
    run = Path(parser.parse_args().run)
    summary = json.loads((run / "summary.json").read_text())
    dataset = Path(summary["dataset"]["path"])
    estimates = read_results(run / "results.csv")
    poses = defaultdict(lambda: ([], []))  # obj_id -> (T_est, T_gt)
    names = {}
    keys = defaultdict(list)  # obj_id -> (scene_id, im_id) per frame, the evaluator's draw keys
    for scene_id in summary["dataset"]["scenes"]:
        scene = Dataset(dataset).scene_dir(scene_id)
        meta, im_ids = read_scene(scene)
        names[meta.obj_id] = meta.end_effector
        for im_id in im_ids:
            found = estimates.get((scene_id, im_id, meta.obj_id))
            poses[meta.obj_id][0].append(found.T_cam_ee if found else np.full((4, 4), np.nan))
            poses[meta.obj_id][1].append(read_frame(scene, im_id).T_cam_ee)
            keys[meta.obj_id].append((scene_id, im_id))
    for obj_id, (T_est, T_gt) in sorted(poses.items()):
        T_est, T_gt = np.stack(T_est), np.stack(T_gt)
        line = []
        for label, max_query in (("all vertices", None), (f"<= {MAX_QUERY} cells", MAX_QUERY)):
            model = load_eval_model(dataset, obj_id, max_query)
            t0 = time.perf_counter()
            points, weights = model.query_points(keys[obj_id])
            e_add = add(T_est, T_gt, points, weights)
            e_adds = adds(T_est, T_gt, points, model.tree, weights)
            seconds = time.perf_counter() - t0
            line.append(f"{label} ({model.n_query} points) ADD {auc(e_add, 0.01):.2f} ADD-S "
                        f"{auc(e_adds, 0.01):.2f} @1cm, ADD {auc(e_add, 0.02):.2f} ADD-S {auc(e_adds, 0.02):.2f} "
                        f"@2cm, {seconds:.1f} s")
        print(f"{names[obj_id]} ({len(T_gt)} frames): " + "; ".join(line))


if __name__ == "__main__":
    main()
