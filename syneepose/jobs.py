"""The render job list: one job = one segment = one BOP scene, in its own worker process.

Scene ids are stable: configuration index in the catalogue x segments per configuration + segment,
so a shard, a resumed run or a `--robots` subset writes the same scene as the full run.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from importlib.metadata import version
from pathlib import Path

import numpy as np

from kernel import bop
from kernel.errors import UserError
from kernel.transforms import inv_T
from syneepose import __version__, paths
from syneepose.preset import Preset, load_preset
from syneepose.robots.catalog import load_catalog
from syneepose.scene.spec import RenderSettings

# BOP methods (SAM-6D, FoundationPose, MegaPose) and bop_toolkit's eval scripts read `test` + test_targets.
SPLIT = "test"
NAME = "syneepose"  # the BOP data set name of result files: METHOD_syneepose-test.csv
@dataclass(frozen=True)
class Job:
    config: str
    scene_id: int
    segment: int
    seed: int
    frames: int
    width: int
    height: int
    samples: int
    out: str
    preset: str
    assets: str
    backgrounds: tuple[str, ...] = ()
    device: str = "cpu"
    marker: bool = False
    depth: str = "exact"  # exact | stereo | both
    sensor: str = "d435"  # a profile in scenes/sensors/ or a YAML path
    segments: int = 1  # per configuration: with the catalogue, it numbers the scenes

    @property
    def scene_dir(self) -> Path:
        """In the split that dataset_info.json (written before any job runs) names, not this process's SPLIT."""
        return bop.split_dir(Path(self.out)) / f"{self.scene_id:06d}"


def parse_shard(text: str | None) -> tuple[int, int]:
    if not text:
        return 0, 1
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise UserError(f"--shard {text!r} must be i/N, e.g. 0/4") from None
    if not (n >= 1 and 0 <= i < n):
        raise UserError(f"--shard {text!r}: need 0 <= i < N")
    return i, n


def make_jobs(preset_name: str, preset: Preset, out: Path, configs: list[str], seed: int, segments: int,
              frames: int, width: int, height: int, samples: int, assets: Path,
              backgrounds: tuple[str, ...] = (), shard: tuple[int, int] = (0, 1), device: str = "cpu",
              marker: bool = False, depth: str = "exact", sensor: str = "d435") -> list[Job]:
    all_configs = load_catalog().configurations
    jobs = []
    for config in configs:
        for segment in range(segments):
            scene_id = all_configs.index(config) * segments + segment
            jobs.append(Job(config, scene_id, segment, seed, frames, width, height, samples, str(out), preset_name,
                            str(assets), backgrounds, device, marker, depth, sensor, segments))
    i, n = shard
    return jobs[i::n]


def job_settings(job: Job) -> dict:
    """What fixes a segment's pixels and ground truth, beside its configuration and scene id: a resume must
    ask for exactly these, or it would mix two renders in one scene. The preset and the sensor profile count
    by content (a sha256 of what was read), not by name."""
    from syneepose.stereo import load_profile

    return {"preset": Path(job.preset).stem, "preset_sha256": _digest(load_preset(job.preset).digest_content()),
            "seed": job.seed, "segments": job.segments, "frames": job.frames,
            "resolution": [job.width, job.height], "samples": job.samples, "device": job.device,
            "marker": job.marker, "depth": job.depth,
            "sensor_sha256": None if job.depth == "exact" else _digest(load_profile(job.sensor).source),
            "backgrounds": [Path(b).name for b in job.backgrounds]}


def _digest(content) -> str:
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:16]


def frames_done(job: Job) -> int:
    return len(bop.complete_frames(job.scene_dir)) if job.scene_dir.is_dir() else 0


def run_job(job: Job) -> int:
    """Worker entry point (fresh process): plan the segment, then render what is missing."""
    from syneepose.blender.segment import render_segment
    from syneepose.robots.ee_models import load_ee_mesh
    from syneepose.robots.robot import load_robot
    from syneepose.scene.motion import MotionChecks
    from syneepose.scene.plan import plan_segment

    preset = load_preset(job.preset)
    robot = load_robot(job.config, Path(job.assets))
    mesh = load_ee_mesh(robot.ee, paths.part_urdf(robot.ee.name, Path(job.assets)))
    spec = plan_segment(preset, robot, MotionChecks(robot, mesh), job.scene_id, job.seed, job.frames,
                        job.width, job.height, list(job.backgrounds))
    if not job.marker:
        spec.marker = None  # a stations plan mounts its board whether it is drawn or not: the plain twin
    elif spec.marker is None:
        spec.marker = _mounted_board(preset, robot, mesh, spec)
    render = RenderSettings(job.width, job.height, job.samples, preset.render.denoise, preset.render.max_bounces,
                            job.device, job.depth, job.sensor)
    with _quiet_stdout():
        return render_segment(spec, render, robot, job.scene_dir, settings=job_settings(job))


def _mounted_board(preset: Preset, robot, mesh, spec):
    """The preset's board turned to face this segment's camera."""
    from syneepose.scene.marker import board_from_preset, mount_facing_camera

    board, mount = board_from_preset(preset)
    radius = float(np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1]).max())
    T_cam_ee = inv_T(spec.T_base_cam) @ robot.T_base_ee(spec.q)
    return mount_facing_camera(board, T_cam_ee, radius, **mount)


@contextmanager
def _quiet_stdout():
    """Blender prints a line per rendered image on the C-level stdout: keep the progress bar readable."""
    saved = os.dup(1)
    with open(os.devnull, "w") as devnull:
        os.dup2(devnull.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)


@dataclass(frozen=True)
class TemplateJob:
    ee: str
    out: str
    views: int
    inplane: int
    resolution: int
    samples: int
    assets: str
    device: str = "cpu"

    @property
    def folder(self) -> Path:
        from kernel.template_set import set_dir

        return set_dir(Path(self.out), self.ee, self.views, self.inplane, self.resolution)

    @property
    def frames(self) -> int:
        return self.views * self.inplane


def templates_done(job: TemplateJob) -> int:
    try:
        return len(json.loads((job.folder / "templates.json").read_text()))
    except (OSError, ValueError):
        return 0


def run_template_job(job: TemplateJob) -> int:
    from syneepose.blender.templates import render_templates

    ee = load_catalog().end_effector(job.ee)
    with _quiet_stdout():
        return render_templates(ee, paths.part_urdf(job.ee, Path(job.assets)), job.folder, job.views, job.inplane,
                                job.resolution, job.samples, job.device)


def write_dataset_info(out: Path, preset_name: str, jobs: list[Job], configs: list[str], assets: Path,
                       settings: dict | None = None) -> None:
    """`settings` (job_settings): what every scene of the data set was rendered with (resume.check_resume)."""
    info_path = out / "dataset_info.json"
    info = bop.read_dataset_info(out)
    first = asdict(jobs[0]) if jobs else {}
    if info.get("split", SPLIT) != SPLIT and info.get("configurations"):
        raise UserError(f"{out} holds a data set in {info['split']}/ (dataset_info.json), renders now write "
                        f"{SPLIT}/; render into another --out (a data set never mixes splits)")
    if info.get("depth", "exact") != first.get("depth", "exact") and info.get("configurations"):
        raise UserError(f"{out} was rendered with --depth {info.get('depth', 'exact')}, not "
                        f"{first.get('depth', 'exact')}; render into another folder (a data set never mixes depth kinds)")
    info.update({
        "name": NAME, "preset": preset_name, "seed": first.get("seed"), "frames_per_segment": first.get("frames"),
        "resolution": [first.get("width"), first.get("height")], "samples": first.get("samples"),
        "configurations": sorted(set(info.get("configurations", [])) | set(configs)),
        "split": SPLIT, "depth_scale": bop.DEPTH_SCALE, "depth": first.get("depth", "exact"),
        "depth_dirs": {"depth": "exact" if first.get("depth", "exact") == "exact" else "stereo sensor",
                       **({"depth_gt": "exact"} if first.get("depth", "exact") != "exact" else {})},
        "versions": {"syneepose": __version__, "bpy": version("bpy")},
    })
    if settings is not None:
        info["settings"] = settings
    if info["depth"] != "exact":
        from syneepose.stereo import load_profile

        info["sensor"] = load_profile(first["sensor"]).source
    tmp = info_path.with_name(f".{info_path.name}.tmp{os.getpid()}")
    tmp.write_text(json.dumps(info, indent=2, sort_keys=True))
    os.replace(tmp, info_path)
    # models_eval/ (BOP's resampled evaluation models) is optional until the assets build makes it.
    for name, source in (("models", paths.models_dir(assets)), ("models_eval", paths.models_eval_dir(assets))):
        if not (out / name).is_dir() and (name == "models" or source.is_dir()):
            staging = out / f".{name}.tmp{os.getpid()}"
            try:
                shutil.copytree(source, staging, ignore=shutil.ignore_patterns(".*"))
                os.replace(staging, out / name)
            except (OSError, shutil.Error) as exc:  # a full disk: no half-copied folder stays
                shutil.rmtree(staging, ignore_errors=True)
                raise UserError(f"cannot copy {source} to {out / name}: {exc}; free space and run again") from None


def write_root_files(out: Path, preset: Preset, width: int, height: int) -> None:
    """camera.json and the test targets over every scene now in `out` (see bop.write_root_files)."""
    from syneepose.scene.sample import nominal_intrinsics

    bop.write_root_files(out, nominal_intrinsics(preset, width, height), width, height)
