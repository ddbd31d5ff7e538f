"""Command line: `python -m syneepose assets | render | templates | dataset | show` (see `--help` of each)."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from kernel.cli import run_command
from kernel.errors import UserError
from kernel.settings import comma_list
from syneepose.preset import HARD_CASES, load_preset, templates_with, with_hard_cases
from syneepose.scene.spec import IR_RENDERS
from syneepose.templates import INPLANE_BY

MAX_WORKERS = 64
MAX_THREADS = 1024


def _assets(args) -> None:
    from syneepose.robots.build import build_assets
    from syneepose.robots.catalog import load_catalog

    configs = load_catalog().parse_configs(args.robots)
    report = build_assets(Path(args.out) if args.out else None, configs, force=args.force)
    if report.did_work:
        print(f"assets: built {len(report.parts)} parts, {len(report.configs)} configurations, "
              f"{len(report.models)} end-effector models in {report.seconds:.1f} s")
    else:
        print(f"assets: up to date ({len(configs)} configurations), nothing to do")


def _resolution(text: str | None) -> list[int] | None:
    """WxH; the sizes are checked with the preset's (syneepose/preset.py)."""
    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise UserError(f"--resolution {text!r} must be WxH, e.g. 640x480") from None
    return [w, h]


def _check_run(args) -> None:
    """The flags that are not preset values."""
    if getattr(args, "seed", 0) < 0:
        raise UserError(f"--seed {args.seed}: must be >= 0 (numpy seeds are non-negative)")
    if args.workers is not None and not 1 <= args.workers <= MAX_WORKERS:
        raise UserError(f"--workers {args.workers}: must lie in 1..{MAX_WORKERS}")
    if args.threads is not None and not 1 <= args.threads <= MAX_THREADS:
        raise UserError(f"--threads {args.threads}: must lie in 1..{MAX_THREADS}")
    if args.gpus is not None and args.device != "gpu":
        raise UserError(f"--gpus {args.gpus} goes with --device gpu; add it, or drop --gpus")
    if args.executor == "ray":
        from syneepose.executors import check_ray_address

        if args.gpus is not None:
            raise UserError(f"--gpus {args.gpus}: with --executor ray each task asks Ray for one GPU and Ray "
                            "picks it; drop --gpus (start the Ray nodes with the GPUs to use)")
        check_ray_address(args.ray_address)
    else:
        _workers(args)  # no GPU, or a --gpus this machine has not: one line before anything is written


def _workers(args) -> list[dict[str, str]]:
    """The environment variables of each local worker: none on a CPU (1 worker by default); with --device gpu
    by default one worker per GPU, each pinned to its own (syneepose/devices.py)."""
    from syneepose.devices import nvidia_smi, visible_gpus, worker_environments

    if args.device == "cpu":
        return [{} for _ in range(args.workers or 1)]
    return worker_environments(args.gpus, args.workers, visible_gpus(os.environ, nvidia_smi()))


def _threads(args) -> int:
    """Cycles threads per job, 0 for every core: locally all cores by default; a Ray task asks Ray for its
    threads as CPUs, so by default one CPU and one thread each, and Ray packs a task per CPU of a node."""
    if args.threads is not None:
        return args.threads
    return 1 if args.executor == "ray" else 0


@dataclass
class Phase:
    """One kind of job of a run, planned and checked, not yet run: its jobs, what each had on disk before,
    what to do after (also after a failure), and the estimated seconds of one unit (ETA of `dataset`)."""

    name: str
    unit: str
    fn: Callable
    jobs: list
    done_before: dict
    unit_seconds: float
    finish: Callable[[], None]  # also after a failure
    summary: str  # printed after success

    @property
    def total(self) -> int:
        return sum(j.frames for j in self.jobs)

    @property
    def todo(self) -> list:
        return [j for j in self.jobs if self.done_before[j] < j.frames]


def _frame_seconds(pixels: int, samples: int) -> float:
    """Estimated seconds of one rendered frame on 2 cores: a fixed part (the segment's plan shared out, scene
    sync, EXR, PNG writes) and one per pixel-sample, fitted to `mini` frames (320x240: 0.93 s at 4 spp in a fresh
    `make dataset`, 1.5 s at 8 spp, 2026-11-28). Only its ratio to `_view_seconds` matters: they share one ETA."""
    return 0.35 + 1.9e-6 * pixels * samples


def _view_seconds(pixels: int, samples: int) -> float:
    """Estimated seconds of one template view on 2 cores, its rolled templates written: the end-effector alone
    costs less a sample than a scene (128 px at 8 spp, 12 rolls: 0.15 s in a fresh `make dataset`, 2026-11-28)."""
    return 1.2e-6 * pixels * samples


def _check_hard_case(name: str) -> None:
    if name not in HARD_CASES:
        raise UserError(f"--hard: unknown hard case {name!r}; choose from {', '.join(HARD_CASES)}")


def _plan_render(args) -> Phase:
    from kernel.bop import SPLIT
    from syneepose import paths, resume
    from syneepose.jobs import (SceneContent, SegmentSelection, frames_done, legacy_preset_digests,
                                make_jobs, parse_shard, run_job, write_dataset_info, write_root_files)
    from syneepose.robots.build import build_assets
    from syneepose.robots.catalog import load_catalog

    _check_run(args)
    preset = load_preset(args.preset, {"segments": args.segments, "frames": args.frames, "samples": args.samples,
                                       "resolution": _resolution(args.resolution)})
    if args.hard:
        preset = with_hard_cases(preset, comma_list(args.hard, "--hard", "hard case",
                                                    f"choose from {', '.join(HARD_CASES)}", _check_hard_case))
    configs = load_catalog().parse_configs(args.robots)
    shard = parse_shard(args.shard)
    backgrounds = ()
    if args.backgrounds:
        folder = Path(args.backgrounds)
        backgrounds = tuple(sorted(str(p) for p in folder.glob("*") if p.suffix.lower() in (".png", ".jpg", ".jpeg")))
        if not backgrounds:
            raise UserError(f"--backgrounds {folder}: no .png/.jpg images found")
    if args.depth != "exact":
        from syneepose.stereo import load_profile

        load_profile(args.sensor, args.sensor_render)  # a bad profile is one error line here, not one per worker
    out = Path(args.out)
    _writable(out)  # after every check of the flags: a mistake writes nothing
    assets = paths.assets_dir()
    build_assets(assets, configs, log=lambda *_: None)
    content = SceneContent(preset, args.preset, args.seed, args.marker, backgrounds)
    width, height = preset.resolution
    render = preset.render_settings(device=args.device, depth=args.depth, sensor=args.sensor, threads=_threads(args),
                                    sensor_render=args.sensor_render)
    plan = make_jobs(content, render, SegmentSelection(tuple(configs), preset.segments, shard), out, assets)
    jobs = plan.jobs
    stale = resume.check_resume(out, jobs, plan.settings, args.overwrite, legacy_preset_digests(content))
    resume.remove_leftovers(out, jobs)
    resume.clear_scenes(stale)
    write_dataset_info(out, plan, assets)

    def finish():  # the root files list what exists, also after a failed or interrupted run; no temp file stays
        resume.remove_leftovers(out, jobs)
        write_root_files(out, preset, width, height)

    return Phase("render", "frame", run_job, jobs, {j: frames_done(j) for j in jobs},
                 _frame_seconds(width * height, preset.samples), finish,
                 f"render: {len(jobs)} segments in {out / SPLIT}")


def _render(args) -> None:
    _run_alone(args, _plan_render(args))


def _run_alone(args, phase: Phase) -> None:
    """One phase under its own bar, counted in its units."""
    from tqdm import tqdm

    bar = tqdm(total=phase.total, initial=sum(phase.done_before.values()), unit=phase.unit, desc=phase.name)

    def report(job):
        bar.update(job.frames - phase.done_before[job])

    try:
        _execute(args, phase.fn, phase.todo, report, bar)
    finally:
        bar.close()
        phase.finish()
    print(phase.summary)


def _dataset(args) -> None:
    """The render and the templates of a data set under one bar whose ETA covers both (make dataset)."""
    from tqdm import tqdm

    from syneepose.robots.catalog import load_catalog

    common = ["--preset", args.preset, "--out", args.out, "--device", args.device, "--executor", args.executor,
              *(["--workers", str(args.workers)] if args.workers is not None else []),
              *(["--gpus", args.gpus] if args.gpus is not None else []),
              *(["--ray-address", args.ray_address] if args.ray_address else []),
              *(["--threads", str(args.threads)] if args.threads is not None else [])]
    configs = load_catalog().parse_configs(args.robots)
    end_effectors = ",".join(dict.fromkeys(c.split("+", 1)[1] for c in configs))
    parser = _parser()
    phases = [_plan_render(parser.parse_args(["render", "--seed", str(args.seed), "--robots", ",".join(configs),
                                              *common])),
              _plan_templates(parser.parse_args(["templates", "--ee", end_effectors, *common]))]
    weight = {p.name: max(round(1000 * p.unit_seconds), 1) for p in phases}  # integer: the updates add up exactly
    done = {p.name: sum(p.done_before.values()) for p in phases}
    bar = tqdm(total=sum(p.total * weight[p.name] for p in phases), initial=sum(done[p.name] * weight[p.name]
               for p in phases), desc="dataset", bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}"
               "{postfix}")

    def show():
        bar.set_postfix_str(", ".join(f"{p.name} {done[p.name]}/{p.total}" for p in phases))

    show()
    try:
        for phase in phases:
            def report(job, phase=phase):
                units = job.frames - phase.done_before[job]
                done[phase.name] += units
                show()
                bar.update(units * weight[phase.name])

            try:
                _execute(args, phase.fn, phase.todo, report, bar)
            finally:
                phase.finish()
    finally:
        bar.close()
    for phase in phases:
        print(phase.summary)


def _execute(args, fn, jobs, report, bar) -> None:
    """Run the jobs; on failure the progress bar is wiped so the error is the last line."""
    from syneepose.executors import run_local, run_ray

    try:
        if args.executor == "ray":
            run_ray(fn, jobs, args.ray_address, report, cpus=max(_threads(args), 1), gpus=int(args.device == "gpu"))
        else:
            run_local(fn, jobs, _workers(args), report)
    except BaseException:
        bar.leave = False
        raise


def _writable(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out} is a file; give a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / ".write-probe").write_text("")
        (out / ".write-probe").unlink()
    except OSError as exc:
        raise UserError(f"cannot write to --out {out}: {exc.strerror}") from exc


def _plan_templates(args) -> Phase:
    from kernel.dataset import Dataset
    from kernel.template_set import check_recipe
    from syneepose import paths
    from syneepose.jobs import TemplateJob, run_template_job, templates_done, write_own_model
    from syneepose.robots.build import build_assets
    from syneepose.robots.catalog import load_catalog
    from syneepose.templates import DENOISE_PREFILTER

    _check_run(args)
    catalog = load_catalog()
    settings = templates_with(load_preset(args.preset), {"views": args.views, "inplane": args.inplane,
                                                         "resolution": args.resolution, "samples": args.samples})
    out = Path(args.out)
    own = _own_end_effector(args)
    names = [own["ee"]] if own else catalog.parse_end_effectors(args.ee)
    _writable(out)
    assets = paths.assets_dir()
    if not own:
        build_assets(assets, [f"panda+{n}" for n in names], log=lambda *_: None)
    source = {key: value for key, value in own.items() if key != "ee"}  # the user's URDF, if any
    jobs = [TemplateJob(n, str(out), settings.views, settings.inplane, settings.resolution, settings.samples,
                        str(assets), args.device, args.inplane_by, _threads(args), **source) for n in names]
    if own:
        model_path = write_own_model(jobs[0], Dataset(out).models_dir)
        print(f"templates: the end-effector's model (mm, in {args.ee_link}'s frame) in {model_path}")
    done_before = {j: templates_done(j) for j in jobs}
    for job in jobs:
        check_recipe(job.folder, job.samples, job.inplane_by, done_before[job] >= job.frames, DENOISE_PREFILTER)
    per_render = _view_seconds(settings.resolution**2, settings.samples)
    return Phase("templates", "template", run_template_job, jobs, done_before,
                 per_render / settings.inplane if args.inplane_by == "rotated" else per_render, lambda: None,
                 f"templates: {len(jobs)} end-effectors in {Dataset(out).templates_dir}")


def _own_end_effector(args) -> dict:
    """--urdf and --ee-link: a user's end-effector, the part of their URDF below that link."""
    if args.urdf is None and args.ee_link is None:
        if args.name or args.mesh_dir:
            raise UserError("--name and --mesh-dir go with --urdf and --ee-link (a URDF's end-effector)")
        return {}
    if args.urdf is None or args.ee_link is None:
        raise UserError("give both --urdf and --ee-link: the robot's URDF and the link the end-effector starts at")
    if args.ee is not None:
        raise UserError("--ee names SynEEPose's end-effectors; with --urdf and --ee-link use --name for the set")
    name = args.name or args.ee_link
    if not name.replace("_", "").replace("-", "").isalnum():
        raise UserError(f"--name {name!r}: use letters, digits, - and _ (it names the template folder)")
    return {"ee": name, "urdf": str(Path(args.urdf).resolve()), "ee_link": args.ee_link,
            "mesh_dir": str(Path(args.mesh_dir).resolve()) if args.mesh_dir else ""}


def _templates(args) -> None:
    _run_alone(args, _plan_templates(args))


def _show(args) -> None:
    from syneepose.show import write_sheets

    root = Path(args.dataset)
    out = Path(args.out) if args.out else root / "contact_sheet.png"
    if out.suffix.lower() != ".png":
        raise UserError(f"--out {out}: give a .png file name")
    sheet, written = write_sheets(root, out, args.frames, args.width)
    print(f"show: {len(sheet.tiles)} configurations in {out}; {len(written) - 1} template sheets beside it")


def _add_execution(p: argparse.ArgumentParser) -> None:
    """Where and how a rendering command runs its jobs: the same options for render, templates and dataset."""
    p.add_argument("--device", choices=["cpu", "gpu"], default="cpu",
                   help="Cycles device; gpu: OptiX, else CUDA, else HIP (one error line when there is no GPU), "
                   "locally one worker per GPU pinned with CUDA_VISIBLE_DEVICES (HIP_VISIBLE_DEVICES on AMD), "
                   "under Ray one GPU per task")
    p.add_argument("--gpus", help="with --device gpu, locally: all (default) or indices such as 0,1,3 among the "
                   "GPUs nvidia-smi lists or CUDA_VISIBLE_DEVICES/HIP_VISIBLE_DEVICES leave visible; a worker each")
    p.add_argument("--executor", choices=["local", "ray"], default="local")
    p.add_argument("--ray-address",
                   help="HOST:PORT of a running Ray cluster, or auto on its head (default: start a local one)")
    p.add_argument("--workers", type=int,
                   help="local worker processes (default 1; with --device gpu one per GPU, N spread over them)")
    p.add_argument("--threads", type=int, help="Cycles threads per job (default: every core locally; 1 per Ray task, "
                   "which asks Ray for as many CPUs)")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m syneepose", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("assets", help="build the robot URDFs and the BOP end-effector models")
    p.add_argument("--out", help="assets folder (default: $SYNEEPOSE_ASSETS or ./assets)")
    p.add_argument("--robots", help="comma-separated ARM+EE configurations (default: all 18)")
    p.add_argument("--force", action="store_true", help="rebuild even when up to date")
    p.set_defaults(func=_assets)
    r = sub.add_parser("render", help="render RGB-D segments in BOP format")
    r.add_argument("--preset", default="mini", help="mini, paper or a YAML path")
    r.add_argument("--out", required=True, help="data set root (BOP: <out>/test/<scene_id>/)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--robots", help="comma-separated ARM+EE configurations (default: all 18)")
    r.add_argument("--segments", type=int, help="segments per configuration (preset default)")
    r.add_argument("--frames", type=int, help="frames per segment (preset default)")
    r.add_argument("--resolution", help="WxH (preset default)")
    r.add_argument("--samples", type=int, help="Cycles samples per pixel (preset default)")
    r.add_argument("--backgrounds", help="folder of images to put on walls at random")
    r.add_argument("--shard", help="i/N: render every N-th segment starting at i (cluster job arrays)")
    r.add_argument("--marker", action="store_true",
                   help="bolt a ChArUco board to the end-effector (marker hand-eye segments; same scenes otherwise)")
    r.add_argument("--hard", help=f"comma-separated hard cases to draw ({', '.join(HARD_CASES)}): an object "
                                  "crossing in front of the end-effector, the end-effector out of view for a run "
                                  "of frames, link-like objects in the arm's colours (the preset's hard: settings "
                                  "or defaults)")
    r.add_argument("--depth", choices=["exact", "stereo", "both"], default="exact",
                   help="stereo: depth/ from a simulated active-stereo sensor, exact depth in depth_gt/; "
                        "both: also keep its IR pair (ir_left/, ir_right/)")
    r.add_argument("--sensor", default="d435", help="sensor profile for --depth stereo|both (scenes/sensors/ or YAML)")
    r.add_argument("--sensor-render", choices=IR_RENDERS,
                   help="the IR pair: shaded from G-buffers (the profile's default, no sampling noise) or pathtraced "
                        "by Cycles (8-12x the cost of an exact-depth frame here; kept for comparison)")
    r.add_argument("--overwrite", action="store_true",
                   help="render this run's scenes again from scratch (a rerun with other settings is refused without it)")
    _add_execution(r)
    r.set_defaults(func=_render)
    t = sub.add_parser("templates", help="render the FEEPE templates of end-effectors")
    t.add_argument("--out", required=True, help="data set root (templates go to <out>/templates/)")
    t.add_argument("--preset", default="mini", help="preset whose `templates` section gives the defaults")
    t.add_argument("--ee", help="comma-separated end-effectors (default: all 6)")
    t.add_argument("--views", type=int, help="views on the Fibonacci sphere (paper: 80)")
    t.add_argument("--inplane", type=int, help="in-plane rotations per view (paper: 12)")
    t.add_argument("--resolution", type=int, help="square image size in pixels")
    t.add_argument("--samples", type=int, help="Cycles samples per pixel")
    t.add_argument("--inplane-by", choices=INPLANE_BY, default="rotated",
                   help="in-plane rotations rolled from each view's one render (default), or each rendered")
    t.add_argument("--urdf", help="your robot's URDF: render the end-effector below --ee-link instead of --ee "
                   "(also writes its model, OUT/models/NAME.ply, for feepe calibrate --model)")
    t.add_argument("--ee-link", help="with --urdf: the link the end-effector starts at (its frame is the model's)")
    t.add_argument("--name", help="with --urdf: the template set's name (default: the --ee-link)")
    t.add_argument("--mesh-dir", help="with --urdf: where package:// mesh paths start (default: beside the URDF)")
    _add_execution(t)
    t.set_defaults(func=_templates)
    s = sub.add_parser("show", help="contact sheet of a data set and a sheet per template set (PNG)")
    s.add_argument("dataset", help="data set root (python -m syneepose render --out DIR)")
    s.add_argument("--out", help="PNG of the contact sheet (default: DATASET/contact_sheet.png); the template "
                   "sheets go beside it as <name>-templates-<set>.png")
    s.add_argument("--frames", type=int, default=4, help="frames per configuration")
    s.add_argument("--width", type=int, default=160, help="width of one frame in pixels")
    s.set_defaults(func=_show)
    d = sub.add_parser("dataset", help="render and templates of a data set under one progress bar (make dataset)")
    d.add_argument("--preset", default="mini", help="mini, paper or a YAML path: its segments and its templates")
    d.add_argument("--out", required=True, help="data set root")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--robots", help="comma-separated ARM+EE configurations (default: all 18); templates for their "
                   "end-effectors")
    _add_execution(d)
    d.set_defaults(func=_dataset)
    return parser


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    return run_command(lambda: args.func(args))


if __name__ == "__main__":
    sys.exit(main())
