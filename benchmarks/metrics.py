"""Metric cost at the paper's scale: ADD, ADD-S and AUC for 54,000 frames (6 end-effectors x 9,000) over
the real evaluation models (models_eval/, every vertex in the ADD-S search, the evaluator's query points). Estimates are GT perturbed like a good method's (80 %
within a few mm and degrees), 10 % flipped by the model's symmetry or turned at random, 10 % missing.

Prints figures; asserts nothing. Run: `.venv/bin/python benchmarks/metrics.py`.
"""

import json
import os
import time

import numpy as np
from scipy.spatial.transform import Rotation

from eval.metrics import add, adds, auc
from eval.model_points import MAX_QUERY, load_eval_model, symmetries_m
from kernel.dataset import MODELS_INFO
from kernel.transforms import make_T
from syneepose import paths
from syneepose.robots.build import build_assets

FRAMES_PER_EE = 9000


def synthetic_poses(rng, n: int, symmetry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T_gt = np.tile(np.eye(4), (n, 1, 1))
    T_gt[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    T_gt[:, :3, 3] = rng.uniform([-0.3, -0.3, 0.5], [0.3, 0.3, 1.5], (n, 3))
    noise = np.tile(np.eye(4), (n, 1, 1))
    noise[:, :3, :3] = Rotation.from_rotvec(rng.normal(0.0, np.radians(1.0), (n, 3))).as_matrix()
    noise[:, :3, 3] = rng.normal(0.0, 0.003, (n, 3))
    T_est = T_gt @ noise
    kind = rng.random(n)
    T_est[kind < 0.05] = T_est[kind < 0.05] @ symmetry
    wild = (kind >= 0.05) & (kind < 0.10)
    T_est[wild, :3, :3] = Rotation.random(int(wild.sum()), random_state=rng).as_matrix()
    T_est[kind >= 0.90] = np.nan
    return T_est, T_gt


def main() -> None:
    build_assets(paths.assets_dir(), log=lambda *_: None)
    info = json.loads((paths.models_eval_dir() / MODELS_INFO).read_text())
    rng = np.random.default_rng(0)
    timings = {"draw": 0.0, "ADD": 0.0, "ADD-S": 0.0, "AUC": 0.0}
    total_points = 0
    for obj_id in sorted(int(k) for k in info):
        model = load_eval_model(paths.assets_dir(), obj_id)
        symmetries = symmetries_m(info[str(obj_id)])
        symmetry = symmetries[0] if symmetries else make_T(Rotation.random(random_state=rng).as_matrix())
        T_est, T_gt = synthetic_poses(rng, FRAMES_PER_EE, symmetry)
        t0 = time.perf_counter()
        points, weights = model.query_points([(obj_id, i) for i in range(FRAMES_PER_EE)])
        t1 = time.perf_counter()
        add_m = add(T_est, T_gt, points, weights)
        t2 = time.perf_counter()
        adds_m = adds(T_est, T_gt, points, model.tree, weights)
        t3 = time.perf_counter()
        scores = [auc(errors, max_error) for errors in (add_m, adds_m) for max_error in (0.01, 0.02)]
        t4 = time.perf_counter()
        timings["draw"] += t1 - t0
        timings["ADD"] += t2 - t1
        timings["ADD-S"] += t3 - t2
        timings["AUC"] += t4 - t3
        total_points += model.n_query
        print(f"obj {obj_id}: {model.n_query} query points per frame, {len(model.vertices)} vertices searched; "
              f"AUC@1cm ADD {scores[0]:.2f} ADD-S {scores[2]:.2f}; {t4 - t0:.1f} s")
    frames = FRAMES_PER_EE * len(info)
    print(f"metrics: {frames} frames, <= {MAX_QUERY} query points per model (mean {total_points / len(info):.0f}), "
          f"{os.cpu_count()} cores: " + ", ".join(f"{k} {v:.1f} s" for k, v in timings.items())
          + f"; total {sum(timings.values()):.1f} s")


if __name__ == "__main__":
    main()
