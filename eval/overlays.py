"""`python -m eval.overlays RESULT_DIR --out DIR [--gif]`: what an `eval.run` result looks like, frame by frame.

Per frame the model's silhouette at the estimated pose (magenta tint and outline, with its x/y/z axes in
red/green/blue) over the RGB, the ground-truth silhouette outlined in yellow, and beside it the same drawn
zoomed on the ground truth; a GIF per segment shows a tracking failure in motion. No renderer: the data
set's BOP mesh (mm -> m) is rasterised at pixel centres, as the data set's masks are, by FEEPE's rasteriser.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import trimesh

from eval.bop_results import read_results
from eval.records import FrameErrors, read_errors
from feepe import raster
from kernel.bop import read_frame
from kernel.camera import project
from kernel.cli import output_dir, run_command
from kernel.dataset import Dataset
from kernel.drawing import BACKGROUND, EST_COLOUR, GT_COLOUR, caption, draw_outline, side_by_side
from kernel.errors import UserError
from kernel.files import read_json, write_gif, write_png
from kernel.transforms import transform_points

AXIS_COLOURS = ((255, 50, 50), (50, 230, 50), (60, 110, 255))  # x, y, z
SHIFT = 4  # OpenCV fixed-point bits: the axes drawn at 1/16 px


@dataclass
class Mesh:
    vertices: np.ndarray  # (n, 3) metres, model frame
    faces: np.ndarray  # (m, 3) int64 vertex indices
    radius: float  # metres, the farthest vertex from the model origin


@lru_cache(maxsize=16)
def load_mesh(path: Path) -> Mesh:
    if not Path(path).is_file():
        raise UserError(f"{path}: missing; the data set's models/ folder must hold the BOP models")
    mesh = trimesh.load(path, process=False, force="mesh")
    vertices = np.asarray(mesh.vertices, dtype=float) / 1000.0
    return Mesh(vertices, np.ascontiguousarray(mesh.faces, dtype=np.int64),
                float(np.linalg.norm(vertices, axis=1).max()))


def silhouette(mesh: Mesh, K: np.ndarray, T_cam_model: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the pixel centres the posed model covers (what lies behind the near plane cut off)."""
    return raster.silhouette(mesh.vertices, mesh.faces, T_cam_model, K, shape)


def draw_axes(image: np.ndarray, K: np.ndarray, T_cam_model: np.ndarray, length: float) -> np.ndarray:
    cam = transform_points(T_cam_model, np.vstack([np.zeros(3), np.eye(3) * length]))
    if (cam[:, 2] > raster.NEAR_M).all():
        origin, *tips = np.round(project(cam, K, min_z=raster.NEAR_M) * (1 << SHIFT)).astype(np.int64)
        for tip, colour in zip(tips, AXIS_COLOURS):
            cv2.line(image, tuple(origin.tolist()), tuple(tip.tolist()), colour, 1, cv2.LINE_AA, SHIFT)
    return image


def draw_pose(rgb: np.ndarray, gt_mask: np.ndarray, K: np.ndarray, mesh: Mesh,
              T_est: np.ndarray | None) -> np.ndarray:
    """The estimate tinted and outlined with its axes, then the ground-truth outline on top."""
    out = rgb.copy()
    if T_est is not None:
        est = silhouette(mesh, K, T_est, gt_mask.shape)
        out[est] = (0.65 * out[est] + 0.35 * np.array(EST_COLOUR)).astype(np.uint8)
        draw_outline(out, est, EST_COLOUR)
        draw_axes(out, K, T_est, 0.5 * mesh.radius)
    return draw_outline(out, gt_mask, GT_COLOUR)


def zoom(rgb: np.ndarray, mask: np.ndarray, K: np.ndarray, size: int,
         margin: float = 0.4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A size x size view around `mask` (its longer side plus `margin` each way): the image, the mask and
    the intrinsics of that view, so the pose is drawn at the zoomed resolution rather than enlarged."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        ys, xs = np.array([0, mask.shape[0] - 1]), np.array([0, mask.shape[1] - 1])
    side = max(np.ptp(xs), np.ptp(ys), 16) * (1 + 2 * margin)
    scale = size / side
    x0, y0 = (xs.min() + xs.max() - side) / 2, (ys.min() + ys.max() - side) / 2
    warp = np.array([[scale, 0, -scale * x0], [0, scale, -scale * y0], [0, 0, 1]])
    rgb = cv2.warpAffine(rgb, warp[:2], (size, size), flags=cv2.INTER_LINEAR, borderValue=BACKGROUND)
    mask = cv2.warpAffine(mask.astype(np.float32), warp[:2], (size, size), flags=cv2.INTER_LINEAR, borderValue=0)
    return rgb, mask > 0.5, warp @ K


def describe(row: FrameErrors) -> str:
    if row.failed:
        return f"seg {row.scene_id} f{row.im_id} no estimate"
    return f"seg {row.scene_id} f{row.im_id} ADD-S {row.adds_m * 1000:.1f} mm"


@dataclass
class ResultFolder:
    """What the overlays need from an `eval.run --out` folder, keyed by (scene id, frame id)."""
    path: Path
    dataset: Path
    estimates: dict[tuple[int, int], np.ndarray]
    errors: dict[tuple[int, int], FrameErrors]

    def frame_overlay(self, scene_id: int, im_id: int) -> np.ndarray:
        """The overlay of one frame, a zoom on the ground truth beside it and a caption line under both."""
        row = self.errors[scene_id, im_id]
        frame = read_frame(Dataset(self.dataset).scene_dir(scene_id), im_id)
        mesh = load_mesh(Dataset(self.dataset).model_path(row.obj_id))
        T_est = self.estimates.get((scene_id, im_id))
        image = side_by_side([draw_pose(frame.rgb, frame.mask, frame.K, mesh, T_est),
                              draw_pose(*zoom(frame.rgb, frame.mask, frame.K, frame.mask.shape[0]), mesh, T_est)])
        return np.vstack([image, caption(image.shape[1], describe(row))])

    def scene_frames(self, scene_id: int) -> list[int]:
        return sorted(im for scene, im in self.errors if scene == scene_id)


def open_results(folder: Path, dataset: Path | None = None) -> ResultFolder:
    """The folder's estimates and errors and its data set (from summary.json unless `dataset` is given)."""
    folder = Path(folder)
    summary_path = folder / "summary.json"
    if not summary_path.is_file():
        raise UserError(f"{summary_path}: missing; give a folder written by python -m eval.run --out")
    recorded = read_json(summary_path, "run python -m eval.run into that folder again")
    if not isinstance(recorded.get("dataset"), dict) or "path" not in recorded["dataset"]:
        raise UserError(f"{summary_path}: not an eval.run summary (no dataset.path); pass --dataset DIR")
    recorded = recorded["dataset"]
    root = Path(dataset or recorded["path"])
    if not Dataset(root).models_dir.is_dir():
        raise UserError(f"{summary_path} names the data set {root}, which has no models/ folder; "
                        "pass --dataset DIR where the data set is now")
    estimates = {(r.scene_id, r.im_id): r.T_cam_ee for r in read_results(folder / "results.csv").values()}
    errors = {(r.scene_id, r.im_id): r for r in read_errors(folder / "errors.csv")}
    return ResultFolder(folder, root, estimates, errors)


def write_overlays(folder: Path, out: Path, scenes: list[int] | None = None, gif: bool = False,
                   fps: float = 4.0, dataset: Path | None = None) -> list[Path]:
    """`out/<scene>/<frame>.png` for every frame of the chosen scenes and, with `gif`, `out/<scene>.gif`."""
    results = open_results(folder, dataset)
    present = sorted({scene for scene, _ in results.errors})
    missing = sorted(set(scenes or ()) - set(present))
    if missing:
        raise UserError(f"--scenes: {folder} has no scene {missing[0]} (it has {present})")
    out = output_dir(out)
    written = []
    for scene_id in scenes or present:
        scene_out = Path(out) / f"{scene_id:06d}"
        scene_out.mkdir(parents=True, exist_ok=True)
        images = []
        for im_id in results.scene_frames(scene_id):
            images.append(results.frame_overlay(scene_id, im_id))
            written.append(scene_out / f"{im_id:06d}.png")
            write_png(written[-1], cv2.cvtColor(images[-1], cv2.COLOR_RGB2BGR))
        if gif:
            written.append(Path(out) / f"{scene_id:06d}.gif")
            write_gif(written[-1], images, fps)
    return written


def _scene_ids(text: str | None) -> list[int] | None:
    if not text:
        return None
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UserError(f"--scenes {text!r} must be comma-separated scene ids, e.g. 0,1,2") from None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m eval.overlays", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("result", type=Path, help="result folder of python -m eval.run")
    parser.add_argument("--out", required=True, type=Path, help="folder for the overlay PNGs (and GIFs)")
    parser.add_argument("--scenes", help="comma-separated scene ids (default: all)")
    parser.add_argument("--gif", action="store_true", help="also write one looping GIF per segment")
    parser.add_argument("--fps", type=float, default=4.0, help="GIF frames per second")
    parser.add_argument("--dataset", type=Path, help="the data set, if it moved since the run")
    args = parser.parse_args(argv)

    def action() -> str:
        if args.fps <= 0:
            raise UserError(f"--fps {args.fps}: must be positive")
        written = write_overlays(args.result, args.out, _scene_ids(args.scenes), args.gif, args.fps, args.dataset)
        return f"overlays: {len(written)} files in {args.out}"

    return run_command(action)


if __name__ == "__main__":
    sys.exit(main())
