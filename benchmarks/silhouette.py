"""The silhouette refinement's rendering on real frames: the z-buffer (feepe/raster.py) against casting a
ray per pixel through trimesh's Embree binding (what the refinement used before), and the contour
extraction with the exact mesh against the 3 mm clustered copy its coarse stages use.

Prints figures, asserts nothing: `make bench` or `.venv/bin/python benchmarks/silhouette.py [--dataset
data/mini] [--frames N]`. Each line times both sides of a ratio side by side on the same frame, whole
robot (`robot_mask_visib/`) and end-effector; ms per call, the median of 5 repeats.
"""

import argparse
import time
from pathlib import Path

import numpy as np
from trimesh.ray.ray_pyembree import RayMeshIntersector

from eval.methods.feepe import arm_models, robot_view
from kernel.camera import backproject
from feepe.silhouette import PartsSilhouette, SilhouetteModel, mask_view
from kernel.dataset import Dataset
from kernel.transforms import inv_T, transform_points


def ray_cast_depth(models, casters, T_cam_parts, K, shape) -> np.ndarray:
    """Every part's first hit along the ray through each pixel centre of its bounding box (the old way)."""
    z = np.zeros(shape)
    for m, rays_of, T in zip(models, casters, T_cam_parts):
        centre = transform_points(T, m.centre[None])[0]
        if centre[2] <= m.radius:
            continue
        c = K[:2, :2] @ (centre[:2] / centre[2]) + K[:2, 2]
        r = m.radius * K[0, 0] / np.sqrt(centre[2] ** 2 - m.radius ** 2) + 1
        u0, u1 = max(0, int(c[0] - r)), min(shape[1], int(np.ceil(c[0] + r)) + 1)
        v0, v1 = max(0, int(c[1] - r)), min(shape[0], int(np.ceil(c[1] + r)) + 1)
        if u0 >= u1 or v0 >= v1:
            continue
        uu, vv = np.meshgrid(np.arange(u0, u1, dtype=float), np.arange(v0, v1, dtype=float))
        T_model_cam = inv_T(T)
        rays = backproject(np.stack([uu.ravel(), vv.ravel()], 1), np.ones(uu.size), K) @ T_model_cam[:3, :3].T
        points, ray, _ = rays_of.intersects_location(np.broadcast_to(T_model_cam[:3, 3], rays.shape).copy(), rays,
                                                     multiple_hits=False)
        zi = np.zeros(rays.shape[0])
        zi[ray] = transform_points(T, points)[:, 2]
        box = z[v0:v1, u0:u1].ravel()
        near = (zi > 0) & ((box == 0) | (zi < box))
        box[near] = zi[near]
        z[v0:v1, u0:u1] = box.reshape(z[v0:v1, u0:u1].shape)
    return z


def timed(fn) -> float:
    fn()
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--dataset", default="data/mini")
    parser.add_argument("--frames", type=int, default=1, help="frames per scene (its middle ones)")
    args = parser.parse_args()
    dataset = Dataset(Path(args.dataset))
    rows = []
    for scene in dataset.scenes():
        meta = scene.meta
        arm = arm_models(meta)
        ee = SilhouetteModel.from_ply(dataset.model_path(meta.obj_id))
        for outline, parts in (("ee", [ee]), ("robot", [ee, *arm[2]])):
            model, casters = PartsSilhouette(parts), [RayMeshIntersector(p.mesh) for p in parts]
            middle = len(scene.im_ids) // 2
            for im_id in scene.im_ids[middle: middle + args.frames]:
                f = scene.frame(im_id)
                links = robot_view(arm, f.link_ids > 0, f.joint_positions).T_base_links
                T = np.einsum("ij,njk->nik", meta.T_cam_base, np.concatenate([f.T_base_ee[None], links])[:len(parts)])
                half = np.diag([0.5, 0.5, 1.0]) @ f.K, (f.mask.shape[0] // 2, f.mask.shape[1] // 2)
                exact = model.render_depth(T, *half)
                old = ray_cast_depth(parts, casters, T, *half)
                view = mask_view(exact > 0, half[0])
                rows.append((outline, sum(len(p.faces) for p in parts), int(((exact > 0) != (old > 0)).sum()),
                             timed(lambda: ray_cast_depth(parts, casters, T, *half)),
                             timed(lambda: model.render_depth(T, *half)),
                             timed(lambda: model.coarse.render_depth(T, *half)),
                             timed(lambda: model.contours(T, f.K, f.mask.shape, 1.0)),
                             timed(lambda: model.coarse.contours(T, f.K, f.mask.shape, 1.0)),
                             view.mask.sum()))
    for outline in ("ee", "robot"):
        r = np.array([row[1:] for row in rows if row[0] == outline], float)
        print(f"{outline}: {len(r)} frames of {dataset.root}, {r[:, 0].mean():.0f} faces, mask IoU render at "
              f"every second pixel ({r[:, 7].mean():.0f} px): Embree ray casting {r[:, 2].mean():.2f} ms, z-buffer "
              f"{r[:, 3].mean():.2f} ms (x{r[:, 2].sum() / r[:, 3].sum():.1f}; {int(r[:, 1].sum())} pixels differ), "
              f"z-buffer of the clustered copy {r[:, 4].mean():.2f} ms; contour extraction, exact mesh "
              f"{r[:, 5].mean():.2f} ms, clustered copy {r[:, 6].mean():.2f} ms (x{r[:, 5].sum() / r[:, 6].sum():.1f})")


if __name__ == "__main__":
    main()
