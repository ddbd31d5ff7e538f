"""`ppf`: point-pair-feature voting + ICP on each frame's masked depth (no temporal prior; feepe/ppf.py).

The pose is the model-frame pose in the camera; the end-effector model comes from `<dataset>/models/`.
"""

from __future__ import annotations

import time
from pathlib import Path

from eval.methods import NoOptions, register
from eval.methods.base import Estimate, Observation
from feepe.icp import SurfaceModel
from feepe.ppf import PpfDetector, PpfOptions, scene_cloud
from kernel.bop import SceneMeta
from kernel.dataset import Dataset
from kernel.errors import UserError


@register("ppf")
class Ppf:
    Options = NoOptions

    def __init__(self, flags: NoOptions):
        self.opts = PpfOptions()
        self._detectors: dict[int, PpfDetector] = {}
        self._current: PpfDetector | None = None

    def options(self) -> dict:
        return {"name": "PPF + ICP", "ppf": vars(self.opts)}

    def inputs(self, meta: SceneMeta, scene_dir: Path) -> list[Path]:
        return [Dataset.of_scene(scene_dir).model_path(meta.obj_id)]

    def given(self, masks: bool, depth: bool) -> None:
        if not (masks and depth):
            raise UserError("--method ppf finds the end-effector in each frame's masked depth: it needs --masks given "
                            "and a depth folder")

    def start_scene(self, meta: SceneMeta, scene_dir: Path) -> None:
        if meta.obj_id not in self._detectors:
            [ply] = self.inputs(meta, scene_dir)
            self._detectors[meta.obj_id] = PpfDetector(SurfaceModel.from_ply(ply), self.opts)
        self._current = self._detectors[meta.obj_id]

    def estimate(self, obs: Observation) -> Estimate:
        start = time.perf_counter()
        found = self._current.detect(*scene_cloud(obs.depth, obs.mask, obs.K, self.opts.max_scene_points))
        elapsed = time.perf_counter() - start
        if found is None:
            return Estimate(T_cam_ee=None, score=0.0, time_s=elapsed)
        T, explained = found
        return Estimate(T_cam_ee=T, score=explained, time_s=elapsed)
