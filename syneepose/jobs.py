"""The render job list: one job = one segment = one BOP scene, in its own worker process.

Scene ids and each segment's random stream come from scene_ids.py: stable, so a shard, a resumed run, a
`--robots` subset or a run with more configurations or segments writes the same scene as the full run.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib.metadata import version
from pathlib import Path

import numpy as np

from kernel import bop
from kernel.dataset import MODELS, MODELS_EVAL, Dataset
from kernel.errors import UserError
from kernel.files import write_json
from kernel.template_set import INDEX
from kernel.transforms import inv_T
from kernel.urdf import mesh_path
from syneepose import __version__, paths, scene_ids
from syneepose.preset import Preset, load_preset
from syneepose.robots.catalog import load_catalog
from syneepose.robots.model import RobotModel, read_urdf, read_urdf_below
from syneepose.scene.spec import RenderSettings

NAME = "syneepose"  # the BOP data set name of result files: METHOD_syneepose-test.csv


@dataclass(frozen=True)
class SceneContent:
    """What a run's segments show beside each one's configuration and segment index: with those it fixes
    a scene (trajectory, camera, lights, backdrop, board), however it is rendered."""

    preset: Preset  # validated with the command line's values (syneepose/preset.py)
    preset_name: str  # --preset as given: a name in scenes/ or a YAML path (recorded, and digested as read)
    seed: int
    marker: bool = False  # a ChArUco board bolted to the end-effector
    backgrounds: tuple[str, ...] = ()  # wall images drawn from at random


@dataclass(frozen=True)
class SegmentSelection:
    """Which segments a run renders: `segments` per configuration, every N-th of them with shard i/N."""

    configs: tuple[str, ...]
    segments: int
    shard: tuple[int, int] = (0, 1)


@dataclass(frozen=True)
class Job:
    key: scene_ids.Key
    scene_id: int
    stream: int  # scene_ids.stream: seeds the segment
    content: SceneContent
    render: RenderSettings
    out: str
    assets: str
    settings: dict = field(compare=False)  # job_settings: recorded with the frames, the same for every job

    def __str__(self) -> str:
        return f"scene {self.scene_id:06d} ({self.key.config}, segment {self.key.segment})"

    @property
    def frames(self) -> int:
        return self.content.preset.frames

    @property
    def scene_dir(self) -> Path:
        """In the split that dataset_info.json (written before any job runs) names, not this process's bop.SPLIT."""
        return Dataset(Path(self.out)).scene_dir(self.scene_id)


@dataclass(frozen=True)
class Plan:
    """A run's jobs (its shard's) and what dataset_info.json records of it."""

    jobs: list[Job]
    scenes: dict[int, scene_ids.Key]  # every scene of the data set after the run, by id (scene_ids.number)
    content: SceneContent
    render: RenderSettings
    selection: SegmentSelection
    settings: dict  # job_settings


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


def make_jobs(content: SceneContent, render: RenderSettings, selection: SegmentSelection, out: Path,
              assets: Path) -> Plan:
    """Reads the data set in `out` for its scene ids (scene_ids.number), and refuses one they cannot be told for."""
    keys = [scene_ids.Key(config, segment) for config in selection.configs for segment in range(selection.segments)]
    scenes, segments = scene_ids.number(out, keys, selection.segments)
    ids, configurations = {key: sid for sid, key in scenes.items()}, load_catalog().configurations
    settings = job_settings(content, render, segments)
    jobs = [Job(key, ids[key], scene_ids.stream(key, segments, configurations), content, render, str(out),
                str(assets), settings) for key in keys]
    i, n = selection.shard
    return Plan(jobs[i::n], scenes, content, render, selection, settings)


def job_settings(content: SceneContent, render: RenderSettings, segments: int) -> dict:
    """What fixes a segment's pixels and ground truth, beside its configuration and segment index: a resume
    must ask for exactly these, or it would mix two renders in one scene. The preset and the sensor profile
    count by content (a sha256 of what was read, with `--hard`'s cases), not by name; `segments` is the data
    set's S (scene_ids.py), which numbers the random streams and stays when a run asks for more segments."""
    from syneepose.stereo import load_profile

    preset = load_preset(content.preset_name).digest_content()
    if content.preset.hard is not None:  # the preset's hard: section with render --hard's cases turned on
        preset["hard"] = content.preset.hard.model_dump(mode="json")
    return {"preset": Path(content.preset_name).stem, "preset_sha256": _digest(preset),
            "seed": content.seed, "segments": segments, "frames": content.preset.frames,
            "resolution": [render.width, render.height], "samples": render.samples, "device": render.device,
            "marker": content.marker, "depth": render.depth,
            "sensor_sha256": None if render.depth == "exact" else _digest(load_profile(render.sensor, render.sensor_render).source),
            "backgrounds": [Path(b).name for b in content.backgrounds]}


def legacy_preset_digests(content: SceneContent) -> set[str]:
    """preset_sha256 values that scenes rendered before issue 16 recorded for the same frames."""
    return {_digest(c) for c in load_preset(content.preset_name).legacy_digest_contents()}


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

    content, render = job.content, job.render
    robot = load_robot(job.key.config, Path(job.assets))
    mesh = load_ee_mesh(robot.ee, paths.part_urdf(robot.ee.name, Path(job.assets)))
    spec = plan_segment(content.preset, robot, MotionChecks(robot, mesh), job.stream, content.seed, job.frames,
                        render.width, render.height, list(content.backgrounds))
    if not content.marker:
        spec.marker = None  # a stations plan mounts its board whether it is drawn or not: the plain twin
    elif spec.marker is None:
        spec.marker = _mounted_board(content.preset, robot, mesh, spec)
    with _quiet_stdout():
        return render_segment(spec, render, robot, mesh, job.scene_dir, settings=job.settings)


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
    inplane_by: str = "rotated"  # templates.INPLANE_BY
    threads: int = 0  # Cycles CPU threads; 0: all cores
    urdf: str = ""  # a user's end-effector: the robot's URDF, `ee` the name of its set, `ee_link` its root link
    ee_link: str = ""
    mesh_dir: str = ""

    @property
    def folder(self) -> Path:
        from kernel.template_set import set_dir

        return set_dir(Path(self.out), self.ee, self.views, self.inplane, self.resolution)

    @property
    def frames(self) -> int:
        return self.views * self.inplane


def templates_done(job: TemplateJob) -> int:
    try:
        return len(json.loads((job.folder / INDEX).read_text()))
    except (OSError, ValueError):
        return 0


def run_template_job(job: TemplateJob) -> int:
    from syneepose.blender.templates import render_templates

    model, urdf_dir, canonical, obj_id = template_model(job)
    with _quiet_stdout():
        return render_templates(model, urdf_dir, canonical, obj_id, job.folder, job.views, job.inplane,
                                job.resolution, job.samples, job.device, inplane=job.inplane_by, threads=job.threads)


def template_model(job: TemplateJob) -> tuple[RobotModel, Path, dict[str, float], int]:
    """What a template job renders: a catalogue end-effector's part URDF at its canonical configuration, or
    the part of a user's URDF below their end-effector link at zero joint values (object id 1)."""
    if job.urdf:
        urdf = Path(job.urdf)
        resolve = lambda name: mesh_path(name, urdf, Path(job.mesh_dir) if job.mesh_dir else None)
        return read_urdf_below(urdf, job.ee_link, resolve), Path("/"), {}, 1
    ee = load_catalog().end_effector(job.ee)
    part = paths.part_urdf(job.ee, Path(job.assets))
    return read_urdf(part), part.parent, dict(ee.canonical), ee.obj_id


def write_own_model(job: TemplateJob, models_dir: Path) -> Path:
    """A user's end-effector as a BOP model (mm, outward normals, vertex colours) beside its templates:
    `models_dir/<name>.ply`, the --model of feepe calibrate."""
    from syneepose.robots.ee_models import orient_outward, rigid_mesh, write_ply_mm

    model, urdf_dir, canonical, _ = template_model(job)
    models_dir.mkdir(parents=True, exist_ok=True)
    path = models_dir / f"{job.ee}.ply"
    write_ply_mm(orient_outward(rigid_mesh(model, urdf_dir, canonical)), path)
    return path


def write_dataset_info(out: Path, plan: Plan, assets: Path) -> None:
    """`plan.settings` (job_settings): what every scene of the data set was rendered with (resume.check_resume)."""
    info = bop.read_dataset_info(out)
    content, render, depth = plan.content, plan.render, plan.render.depth
    if info.get("split", bop.SPLIT) != bop.SPLIT and info.get("configurations"):
        raise UserError(f"{out} holds a data set in {info['split']}/ (dataset_info.json), renders now write "
                        f"{bop.SPLIT}/; render into another --out (a data set never mixes splits)")
    if info.get("depth", "exact") != depth and info.get("configurations"):
        raise UserError(f"{out} was rendered with --depth {info.get('depth', 'exact')}, not {depth}; render into "
                        "another folder (a data set never mixes depth kinds)")
    info.update({
        "name": NAME, "preset": content.preset_name, "seed": content.seed, "frames_per_segment": content.preset.frames,
        "resolution": [render.width, render.height], "samples": render.samples,
        "configurations": sorted(set(info.get("configurations", [])) | set(plan.selection.configs)),
        "split": bop.SPLIT, "depth_scale": bop.DEPTH_SCALE, "depth": depth,
        "depth_dirs": {bop.DEPTH_DIR: "exact" if depth == "exact" else "stereo sensor",
                       **({bop.DEPTH_GT_DIR: "exact"} if depth != "exact" else {})},
        "versions": {"syneepose": __version__, "bpy": version("bpy")}, "settings": plan.settings,
        "scenes": {str(sid): {"config": key.config, "segment": key.segment} for sid, key in plan.scenes.items()},
    })
    if depth != "exact":
        from syneepose.stereo import load_profile

        info["sensor"] = load_profile(render.sensor, render.sensor_render).source
    write_json(out / bop.DATASET_INFO, info)
    # models_eval/ (BOP's resampled evaluation models) is optional until the assets build makes it.
    for name, source in ((MODELS, paths.models_dir(assets)), (MODELS_EVAL, paths.models_eval_dir(assets))):
        if not (out / name).is_dir() and (name == MODELS or source.is_dir()):
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
