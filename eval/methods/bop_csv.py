"""`bop-csv`: the estimates of a method we cannot run here (MegaPose, SAM-6D, FoundationPose need GPU
weights), read from its BOP results CSV and replayed frame by frame."""

from __future__ import annotations

from pathlib import Path

from eval.bop_results import BopResult, read_results
from eval.methods import register
from eval.methods.base import Estimate, Observation
from syneepose.bop import SceneMeta, read_json
from syneepose.errors import UserError


@register("bop-csv")
class BopCsv:
    def __init__(self, results: str, name: str):
        self.results, self.label = Path(results), name
        self._by_key: dict[tuple[int, int, int], BopResult] | None = None
        self._scene_id = self._obj_id = -1

    def options(self) -> dict:
        return {"results": str(self.results.resolve()), "name": self.label}

    def inputs(self, meta: SceneMeta, scene_dir: Path) -> list[Path]:
        return [self.results]

    def start_scene(self, meta: SceneMeta, scene_dir: Path) -> None:
        """The first scene also validates the CSV against the data set (root/split/scene)."""
        scene_dir = Path(scene_dir)
        if self._by_key is None:
            models_info = scene_dir.parents[1] / "models" / "models_info.json"
            if not models_info.is_file():
                raise UserError(f"{models_info}: missing; the data set needs its models/ folder")
            scene_ids = [int(p.name) for p in scene_dir.parent.iterdir() if p.name.isdigit()]
            self._by_key = read_results(self.results, (int(k) for k in read_json(models_info, "copy the models again")),
                                        scene_ids)
        self._scene_id, self._obj_id = int(scene_dir.name), meta.obj_id

    def estimate(self, obs: Observation) -> Estimate:
        found = self._by_key.get((self._scene_id, obs.im_id, self._obj_id))
        if found is None:
            return Estimate(T_cam_ee=None, score=0.0, time_s=-1.0)
        return Estimate(T_cam_ee=found.T_cam_ee, score=found.score, time_s=found.time_s)
