"""`bop-csv`: the estimates of a method we cannot run here (MegaPose, SAM-6D, FoundationPose need GPU
weights), read from its BOP results CSV and replayed frame by frame."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from eval.bop_results import BopResult, read_results
from eval.methods import option, register
from eval.methods.base import Estimate, Observation
from kernel.bop import SceneMeta
from kernel.dataset import Dataset
from kernel.errors import UserError


@dataclass(frozen=True)
class BopCsvFlags:
    results: str = option(help="the BOP results CSV to score")
    name: str = option(help="the label of those results (e.g. MegaPose)")


@register("bop-csv")
class BopCsv:
    Options = BopCsvFlags

    def __init__(self, flags: BopCsvFlags):
        self.results, self.label = Path(flags.results), flags.name
        self._by_key: dict[tuple[int, int, int], BopResult] | None = None
        self._scene_id = self._obj_id = -1

    def options(self) -> dict:
        return {"results": str(self.results.resolve()), "name": self.label}

    def inputs(self, meta: SceneMeta, scene_dir: Path) -> list[Path]:
        return [self.results]

    def check(self, scenes: dict[int, list[int]], split_dir: Path) -> None:
        """Every row must name an object, a scene and a frame of the data set: a row that cannot be placed is a
        mistake in the file (another split, another data set), not a frame to skip."""
        self._by_key = read_results(self.results, Dataset(Path(split_dir).parent).obj_ids(), list(scenes))
        frames = {s: set(ids) for s, ids in scenes.items()}
        stray = sorted((s, i) for s, i, _ in self._by_key if i not in frames[s])
        if stray:
            raise UserError(f"{self.results}: {len(stray)} row(s) name frames the data set lacks (first: scene "
                            f"{stray[0][0]} frame {stray[0][1]}); results of another data set or split?")

    def start_scene(self, meta: SceneMeta, scene_dir: Path) -> None:
        self._scene_id, self._obj_id = int(Path(scene_dir).name), meta.obj_id

    def estimate(self, obs: Observation) -> Estimate:
        found = self._by_key.get((self._scene_id, obs.im_id, self._obj_id))
        if found is None:
            return Estimate(T_cam_ee=None, score=0.0, time_s=-1.0)
        return Estimate(T_cam_ee=found.T_cam_ee, score=found.score, time_s=found.time_s)
