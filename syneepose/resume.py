"""A rerun into an existing data set: checked before anything renders, so it resumes, refuses or re-renders,
and never mixes two settings in one data set (dataset_info.json then describes every file).

Each segment records the settings that rendered it (`scene_robot.json` "settings", jobs.job_settings); a
data set rendered before they were recorded is judged by what its dataset_info.json says. More --robots or
--segments are not other settings: they add scenes, and every scene keeps its id (scene_ids.py).
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

from kernel import bop, files
from kernel.errors import UserError
from syneepose.jobs import Job

# dataset_info.json keys of data sets from before per-segment settings, and the settings they stand for
_LEGACY = {"seed": "seed", "frames_per_segment": "frames", "resolution": "resolution", "samples": "samples",
           "depth": "depth"}
_TEMP = re.compile(r"^(tmp\w*\.exr|\..+\.tmp\d+)$")  # Blender's mkstemp EXRs, files.write_atomic's temp names
_OWNED = re.compile(r"^\..+\.(?:tmp|overwritten)(\d+)$")  # staged models, dataset_info, scenes being cleared: by pid


def recorded_settings(out: Path) -> dict | None:
    """The settings dataset_info.json records (the legacy subset for older data sets); None without one."""
    info = bop.read_dataset_info(out)
    if isinstance(info.get("settings"), dict):
        return info["settings"]
    return {new: info[old] for old, new in _LEGACY.items() if old in info} or None


def _has_files(scene_dir: Path) -> bool:
    return any(p.is_file() and not _TEMP.match(p.name) for p in scene_dir.rglob("*"))


def _scene_settings(scene_dir: Path, fallback: dict | None) -> dict | None:
    robot = bop.record_paths(scene_dir)["scene_robot"]
    if robot.is_file():
        record = files.read_json(robot)
        if isinstance(record.get("settings"), dict):
            return record["settings"]
    return fallback


def check_resume(out: Path, jobs: list[Job], settings: dict, overwrite: bool,
                 same_preset: set[str] = frozenset()) -> list[Path]:
    """The scene folders this run must clear first (only with `overwrite`: all of this run's scenes that
    hold files). Raises when a scene of the data set was rendered with other settings and would stay.
    `same_preset`: older preset_sha256 values of this run's preset (jobs.legacy_preset_digests)."""
    out = Path(out)
    fallback = recorded_settings(out)
    ours = {job.scene_dir for job in jobs}
    other = []  # (scene folder, its differences)
    for scene_dir in bop.scene_dirs(bop.split_dir(out)).values():
        if not _has_files(scene_dir):
            continue
        before = _scene_settings(scene_dir, fallback)
        if before is None:
            continue
        if before.get("preset_sha256") in same_preset:
            before = {**before, "preset_sha256": settings["preset_sha256"]}
        shared = {k: v for k, v in settings.items() if k in before}
        if {k: before[k] for k in shared} != shared:
            other.append((scene_dir, bop.settings_diff({k: before[k] for k in shared}, shared)))
    if other and not overwrite:
        scene_dir, diff = other[0]
        raise UserError(f"{out}: {len(other)} scene(s) were rendered with other settings ({scene_dir.name}: {diff}); "
                        "rerun with the same settings to resume, --overwrite to render this run's scenes again, "
                        "or render into another --out")
    staying = [s for s, _ in other if s not in ours]
    if staying:
        raise UserError(f"{out}: --overwrite re-renders this run's scenes only, and {len(staying)} other scene(s) "
                        f"({', '.join(s.name for s in staying[:5])}) hold other settings ({other[0][1]}); "
                        "add their configurations to --robots, or render into another --out")
    return sorted(s for s in ours if overwrite and s.is_dir() and _has_files(s))


def clear_scenes(scene_dirs: list[Path]) -> None:
    """Each folder renamed aside first, so a kill mid-delete leaves no half scene under its id."""
    for scene_dir in scene_dirs:
        aside = scene_dir.with_name(f".{scene_dir.name}.overwritten{os.getpid()}")
        os.replace(scene_dir, aside)
        shutil.rmtree(aside)


def remove_leftovers(out: Path, jobs: list[Job]) -> int:
    """Temp files a killed run left in this run's scenes (Blender's EXRs, half-written JSON and PNG), and
    temp folders at the root whose writing process is gone; how many were removed."""
    removed = 0
    for job in jobs:
        if job.scene_dir.is_dir():
            for path in job.scene_dir.rglob("*"):
                if path.is_file() and _TEMP.match(path.name):
                    path.unlink()
                    removed += 1
    for path in [*Path(out).glob(".*"), *bop.split_dir(out).glob(".*")]:
        owner = _OWNED.match(path.name)
        if owner and not _alive(int(owner.group(1))):
            shutil.rmtree(path) if path.is_dir() else path.unlink()
            removed += 1
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
