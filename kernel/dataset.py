"""A BOP data set on disk as one object: where each of its folders and files lives, and its scenes.

    <root>/dataset_info.json   our record of what rendered it (split, preset, settings, scene ids)
    <root>/camera.json, test_targets_bop19.json, test_targets_bop24.json   BOP root files
    <root>/models/, models_eval/   BOP models (mm) with models_info.json
    <root>/templates/<ee>_<views>x<inplane>_<res>px/   FEEPE template sets (kernel/template_set.py)
    <root>/<split>/<scene_id:06d>/   BOP scenes with our robot sidecar (kernel/bop.py)

Readers and writers of the files themselves are plain functions in kernel/bop.py, kernel/template_set.py and
kernel/files.py; this object only knows the layout. The names are spelt here and in kernel/bop.py (the split, the
root record, a scene's folders), so no module outside kernel/ spells a folder or file name of the data set.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from kernel.bop import (DEPTH_DIR, Frame, SceneMeta, frame_paths, image_path, read_dataset_info, read_frame,
                        read_gt_poses, read_scene, record_paths, scene_dirs, split_name)
from kernel.errors import UserError
from kernel.files import read_json, read_png

MODELS, MODELS_EVAL, TEMPLATES = "models", "models_eval", "templates"
MODELS_INFO = "models_info.json"  # in models/ and models_eval/
MODELS_NAMES = "models_names.json"  # in models/: obj_id -> end-effector name (ours, not BOP)


def model_name(obj_id: int) -> str:
    return f"obj_{obj_id:06d}.ply"


@dataclass(frozen=True)
class Scene:
    """One BOP scene (a video segment): its meta, its complete frames and readers of them."""
    scene_id: int
    path: Path
    meta: SceneMeta
    im_ids: list[int]

    @property
    def config(self) -> str:
        return f"{self.meta.arm}+{self.meta.end_effector}"

    def frame(self, im_id: int) -> Frame:
        return read_frame(self.path, im_id)

    def gt_poses(self) -> dict[int, np.ndarray]:
        return read_gt_poses(self.path)

    @cached_property
    def cameras(self) -> dict:
        """scene_camera.json by frame id (as text, as BOP keys it)."""
        return read_json(record_paths(self.path)["scene_camera"])

    def inputs(self, depth_folder: str | None = DEPTH_DIR) -> tuple[dict[str, Path], dict[str, Path]]:
        """Every file reading this scene's frames opens (`read_scene`, `frame`, `depth(.., depth_folder)`;
        None: no other depth): its JSON records, then each frame's images, both by their path relative to the
        scene folder. A result computed from the scene is fingerprinted by exactly these."""
        robot = read_json(record_paths(self.path)["scene_robot"])
        images = {}
        for im_id in self.im_ids:
            paths = list(frame_paths(self.path, im_id, robot).values())
            if depth_folder is not None:
                paths.append(image_path(self.path, depth_folder, im_id))
            images.update((p.relative_to(self.path).as_posix(), p) for p in paths)
        records = {p.name: p for p in record_paths(self.path).values() if p.is_file()}
        return records, images

    def depth(self, im_id: int, folder: str = DEPTH_DIR) -> np.ndarray:
        """A frame's depth in metres from `folder` (`depth`, or another sensor's beside it, e.g. `depth_gt`)."""
        path = image_path(self.path, folder, im_id)
        if not path.is_file():
            raise UserError(f"{path}: missing; depth folder {folder!r} must sit beside depth/ in every scene")
        return read_png(path) * (self.cameras[str(im_id)]["depth_scale"] / 1000.0)


@dataclass(frozen=True)
class Dataset:
    root: Path

    @classmethod
    def of_scene(cls, scene_dir: Path) -> Dataset:
        """The data set a scene folder belongs to (`<root>/<split>/<scene>`)."""
        return cls(Path(scene_dir).parents[1])

    @cached_property
    def info(self) -> dict:
        """dataset_info.json ({} for a folder without one)."""
        return read_dataset_info(self.root)

    @property
    def split(self) -> str:
        return split_name(self.root)

    @property
    def split_dir(self) -> Path:
        return self.root / self.split

    @property
    def models_dir(self) -> Path:
        return self.root / MODELS

    @property
    def models_eval_dir(self) -> Path:
        return self.root / MODELS_EVAL

    @property
    def templates_dir(self) -> Path:
        return self.root / TEMPLATES

    def model_path(self, obj_id: int) -> Path:
        """The BOP model (.ply, mm) that methods read."""
        return self.models_dir / model_name(obj_id)

    def eval_model_path(self, obj_id: int) -> Path:
        """The resampled model pose errors are computed on (BOP's models_eval/)."""
        return self.models_eval_dir / model_name(obj_id)

    def obj_ids(self) -> list[int]:
        """The objects of models/models_info.json."""
        path = self.models_dir / MODELS_INFO
        if not path.is_file():
            raise UserError(f"{path}: missing; the data set needs its models/ folder")
        return sorted(int(k) for k in read_json(path, "copy the models again (python -m syneepose render)"))

    def scene_dir(self, scene_id: int) -> Path:
        """Where scene `scene_id` is (or will be) written."""
        return self.split_dir / f"{scene_id:06d}"

    def scene_dirs(self) -> dict[int, Path]:
        """The scene folders present, by id."""
        return scene_dirs(self.split_dir)

    def scene(self, scene_id: int) -> Scene:
        path = self.scene_dirs().get(scene_id)
        if path is None:
            raise UserError(f"scene {scene_id} is not in {self.split_dir}")
        return Scene(scene_id, path, *read_scene(path))

    def scenes(self) -> list[Scene]:
        """Every scene of the split, by id (a scene folder without a complete frame is a UserError)."""
        return [Scene(i, path, *read_scene(path)) for i, path in self.scene_dirs().items()]
