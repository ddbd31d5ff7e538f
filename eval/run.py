"""`python -m eval.run`: run a method over a BOP data set, frame by frame in order, and score it.

Writes <out>/results.csv (BOP; copied as <method>_<dataset>-<split>.csv, the name the BOP toolkit's
scripts parse), <out>/errors.csv (one row per frame) and <out>/summary.json. Each scene's rows go to
<out>/scenes/ as soon as the scene is done, with a fingerprint of every file it was computed from; a rerun
resumes with the scenes that are missing and runs again every scene whose inputs changed; when only the
evaluation model or the metric changed, it scores the scene's stored estimates again without the method.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.metadata
import importlib.util
import json
import subprocess
import sys
import time
import typing
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eval.bop_results import BopResult, read_results, write_results
from eval.fingerprint import differences, only_scoring_changed, read_fingerprint, scene_fingerprint
from eval.mask_noise import MaskNoise, frame_rng, mask_noise, perturb
from eval.methods import build_method, flag, get_method, known_methods, required, takes
from eval.methods.base import Estimate, Observation
from eval.metrics import WORKSPACE_POINTS, add, adds, calibration_error, rotation_error_deg, translation_error_mm
from eval.model_points import QUERY_RULE, QUERY_RULE_TEXT, EvalModel, load_eval_model
from eval.records import FrameErrors, read_errors, write_errors
from eval.summary import summarise
from kernel.bop import DEPTH_DIR, MASK_VISIB_DIR, complete_frames, image_path, object_mask_path
from kernel.cli import run_command
from kernel.dataset import Dataset, Scene
from kernel.errors import UserError
from kernel.files import read_json, write_atomic, write_png
from kernel.settings import comma_list

NO_POSE = np.full((4, 4), np.nan)


def find_scenes(dataset: Dataset, scenes: str | None, robots: str | None) -> list[Scene]:
    if not dataset.root.is_dir():
        raise UserError(f"--dataset {dataset.root}: no such folder; give the root of a BOP data set")
    split_dir = dataset.split_dir
    if not split_dir.is_dir():
        raise UserError(f"--dataset {dataset.root}: no {split_dir.name}/ folder; give the root of a BOP data "
                        "set (python -m syneepose render --out DIR)")
    present = dataset.scene_dirs()
    ids = sorted(present)
    if scenes:
        def is_id(text: str) -> None:
            if not text.isdigit():
                raise UserError(f"--scenes {scenes!r} must be comma-separated scene ids, e.g. 0,1,2")

        ids = [int(v) for v in comma_list(scenes, "--scenes", "scene", "give ids, e.g. 0,1,2, or leave it out for all",
                                          is_id)]
        missing = [i for i in ids if i not in present]
        if missing:
            raise UserError(f"--scenes: scene {missing[0]} is not in {split_dir} (it has {len(present)} scenes)")
    found = [dataset.scene(i) for i in ids]
    if robots:
        from syneepose.robots.catalog import load_catalog

        wanted = set(load_catalog().parse_configs(robots))
        found = [s for s in found if s.config in wanted]
    if not found:
        raise UserError(f"--dataset {dataset.root}: no scene matches --scenes {scenes} --robots {robots}")
    return found


NO_DEPTH = "none"  # --depth-dir none: the method sees no depth (an RGB camera)
MASKS = ("given", "none")  # --masks: the data set's masks are handed in (perhaps perturbed), or no mask at all


def observation(scene: Scene, im_id: int, depth_dir: str, noise: MaskNoise | None, masks: str = "given"):
    """The observation a method sees, the ground truth T_cam_ee it is scored against, and the true visible
    masks (end-effector, robot or None) its own masks are scored against."""
    frame = scene.frame(im_id)
    robot = None if frame.link_ids is None else frame.link_ids > 0
    truth = (frame.mask_visib, robot)
    if masks == "none":
        mask = robot = None
    elif noise is not None:  # the end-effector's draw first: runs from before robot masks see the same masks
        rng = frame_rng(noise, scene.scene_id, im_id)
        mask = perturb(frame.mask_visib, noise, rng)
        robot = None if robot is None else perturb(robot, noise, rng)
    else:
        mask = frame.mask_visib
    depth = (None if depth_dir == NO_DEPTH else frame.depth if depth_dir == DEPTH_DIR
             else scene.depth(im_id, depth_dir))
    obs = Observation(im_id=im_id, rgb=frame.rgb, depth=depth, mask=mask, K=frame.K,
                      joint_positions=frame.joint_positions, T_base_ee=frame.T_base_ee, robot_mask=robot)
    return obs, frame.T_cam_ee, truth


def _pose(T) -> np.ndarray:
    return NO_POSE if T is None else np.asarray(T, dtype=float)


def _pose_errors(scene: Scene, im_ids: list[int], T_est: np.ndarray, T_gt: np.ndarray,
                 model: EvalModel) -> tuple[np.ndarray, np.ndarray]:
    """ADD and ADD-S (m) per frame, the query points drawn from each frame's (scene_id, im_id)."""
    points, weights = model.query_points([(scene.scene_id, im_id) for im_id in im_ids])
    return add(T_est, T_gt, points, weights), adds(T_est, T_gt, points, model.tree, weights)


def mask_ious(estimate: Estimate, truth: tuple) -> tuple[float, float]:
    """IoU of the method's own end-effector and robot masks against the true visible ones: NaN when the
    method makes no masks (`masks` None), 0 for a mask it makes but left out of this frame."""
    made = estimate.masks
    if made is None:
        return np.nan, np.nan
    out = []
    for name, true in zip(("ee", "robot"), truth):
        if true is None:
            out.append(np.nan)
            continue
        mine = made.get(name, np.zeros_like(true))
        union = np.count_nonzero(mine | true)
        out.append(np.count_nonzero(mine & true) / union if union else 1.0)
    return out[0], out[1]


def score_scene(scene: Scene, T_gt: np.ndarray, estimates: list[Estimate], wall_s: list[float],
                model: EvalModel, ious: list[tuple[float, float]] | None = None) -> list[FrameErrors]:
    T_est = np.stack([_pose(e.T_cam_ee) for e in estimates])
    T_base = np.stack([_pose(e.T_cam_base) for e in estimates])
    add_m, adds_m = _pose_errors(scene, scene.im_ids, T_est, T_gt, model)
    rot, trans = rotation_error_deg(T_est, T_gt), translation_error_mm(T_est, T_gt)
    T_cam_base = scene.meta.T_cam_base
    calib = calibration_error(T_base, T_cam_base, WORKSPACE_POINTS)
    calib_trans, calib_rot, calib_points = calib.trans_mm, calib.rot_deg, calib.points_mm.mean(axis=1)
    return [FrameErrors(scene_id=scene.scene_id, im_id=im_id, obj_id=scene.meta.obj_id, config=scene.config,
                        end_effector=scene.meta.end_effector, add_m=float(add_m[i]), adds_m=float(adds_m[i]),
                        rot_err_deg=float(rot[i]), trans_err_mm=float(trans[i]),
                        calib_trans_mm=float(calib_trans[i]), calib_rot_deg=float(calib_rot[i]),
                        time_s=float(e.time_s), score=float(e.score) if e.T_cam_ee is not None else np.nan,
                        wall_s=wall_s[i], calib_points_mm=float(calib_points[i]),
                        ee_mask_iou=float(ious[i][0]) if ious else np.nan,
                        robot_mask_iou=float(ious[i][1]) if ious else np.nan)
            for i, (im_id, e) in enumerate(zip(scene.im_ids, estimates))]


def rescore_scene(out: Path, scene: Scene, model: EvalModel) -> list[FrameErrors]:
    """The scene's stored rows with ADD / ADD-S computed again from its stored estimates (results.csv) and
    ground truth; every other column is what the method's run wrote."""
    results_csv, errors_csv, _ = _scene_files(out, scene.scene_id)
    results, rows = read_results(results_csv), sorted(read_errors(errors_csv), key=lambda r: r.im_id)
    found = [results.get((scene.scene_id, r.im_id, scene.meta.obj_id)) for r in rows]
    T_est = np.stack([NO_POSE if f is None else f.T_cam_ee for f in found])
    gt = scene.gt_poses()
    add_m, adds_m = _pose_errors(scene, [r.im_id for r in rows], T_est, np.stack([gt[r.im_id] for r in rows]), model)
    return [dataclasses.replace(r, add_m=float(a), adds_m=float(b)) for r, a, b in zip(rows, add_m, adds_m)]


def run_scene(method, scene: Scene, depth_dir: str, model: EvalModel, bar, noise: MaskNoise | None = None,
              masks: str = "given", out: Path | None = None) -> tuple[list, list]:
    """The method over one scene in frame order; returns its BOP results and its error rows. The masks a
    method makes itself go to `out`/masks/ (own_masks_dir)."""
    method.start_scene(dataclasses.replace(scene.meta, T_cam_base=NO_POSE.copy()), scene.path)
    T_gt, estimates, wall_s, ious = [], [], [], []
    for im_id in scene.im_ids:
        obs, T_cam_ee, truth = observation(scene, im_id, depth_dir, noise, masks)
        start = time.perf_counter()
        estimate = method.estimate(obs)
        wall_s.append(time.perf_counter() - start)
        estimates.append(estimate)
        ious.append(mask_ious(estimate, truth))
        if estimate.masks and out is not None:
            write_own_masks(out, scene.scene_id, im_id, estimate.masks)
        T_gt.append(T_cam_ee)
        bar.update()
    results = [BopResult(scene.scene_id, im_id, scene.meta.obj_id, e.score, e.T_cam_ee, e.time_s)
               for im_id, e in zip(scene.im_ids, estimates) if e.T_cam_ee is not None]
    return results, score_scene(scene, np.stack(T_gt), estimates, wall_s, model, ious)


def own_masks_dir(out: Path, scene_id: int) -> Path:
    """Where a run keeps the masks its method made, as a BOP scene keeps its own: mask_visib/ (the
    end-effector, `<im_id>_000000.png`) and robot_mask/ (the whole robot), 0 or 255 per pixel."""
    return Path(out) / "masks" / f"{scene_id:06d}"


def write_own_masks(out: Path, scene_id: int, im_id: int, masks: dict) -> None:
    folder = own_masks_dir(out, scene_id)
    for name, path in (("ee", object_mask_path(folder, MASK_VISIB_DIR, im_id)),
                       ("robot", image_path(folder, "robot_mask", im_id))):
        if name in masks:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_png(path, np.asarray(masks[name], bool).astype(np.uint8) * 255)


def _scene_files(out: Path, scene_id: int) -> tuple[Path, Path, Path]:
    """Results, errors and fingerprint of one scene, written in that order."""
    stem = out / "scenes" / f"{scene_id:06d}"
    return stem.with_suffix(".results.csv"), stem.with_suffix(".errors.csv"), stem.with_suffix(".fingerprint.json")


def _store_scene(out: Path, scene_id: int, fingerprint: dict, errors: list[FrameErrors],
                 results: list[BopResult] | None = None) -> None:
    """A scene's rows (its results too when the method ran), the fingerprint last: an interrupted write leaves
    no fingerprint, so the scene is done again."""
    results_csv, errors_csv, fp_path = _scene_files(out, scene_id)
    fp_path.unlink(missing_ok=True)
    if results is not None:
        write_results(results_csv, results)
    write_errors(errors_csv, errors)
    write_atomic(fp_path, json.dumps(fingerprint, indent=1).encode())


def _method_inputs(method, scene: Scene) -> list[Path]:
    """The files a method reads besides the frames (e.g. FEEPE's template set), if it says."""
    inputs = getattr(method, "inputs", None)
    return [Path(p) for p in inputs(scene.meta, scene.path)] if inputs else []


def _scene_ids(ids: list[int]) -> str:
    """'scene 3' or 'scenes 0-5, 9': consecutive ids as ranges, so a changed data set says one line."""
    runs = []
    for i in ids:
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    text = ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)
    return f"scene {text}" if len(ids) == 1 else f"scenes {text}"


def _stale(out: Path, scene: Scene, fingerprint: dict) -> tuple[list[str] | None, bool]:
    """(None, _) when the scene's stored rows were computed from exactly these inputs; else what changed,
    and whether only the scoring changed (the stored estimates stand and are scored again)."""
    results_csv, errors_csv, fp_path = _scene_files(out, scene.scene_id)
    if not (results_csv.is_file() and errors_csv.is_file()):
        return [], False
    before = read_fingerprint(fp_path)
    if before is None:
        return ["no fingerprint of its inputs (scored by an older version)"], False
    changed = differences(before, fingerprint)
    return (changed, only_scoring_changed(before, fingerprint)) if changed else (None, False)


def _claim(out: Path, identity: dict) -> None:
    """An out folder belongs to one run: resuming with another method, options or data set is refused. (The
    metric is not part of it: a changed metric scores the stored estimates again, scene by scene.)"""
    identity = json.loads(json.dumps(identity))  # as it reads back from run.json
    path = out / "run.json"
    if path.is_file():
        before = read_json(path, "delete the --out folder or use another")
        changed = sorted(k for k in set(identity) | set(before) if before.get(k) != identity.get(k))
        if changed:
            raise UserError(f"--out {out} holds a run with other {', '.join(changed)} ({path}); "
                            "use another --out or delete it")
    try:
        (out / "scenes").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot write to --out {out}: {exc.strerror}") from exc
    write_atomic(path, json.dumps(identity, indent=2, sort_keys=True).encode())


def _versions() -> dict:
    import cv2
    import scipy

    versions = {"numpy": np.__version__, "scipy": scipy.__version__, "cv2": cv2.__version__,
                "syneepose": importlib.metadata.version("syneepose")}
    if importlib.util.find_spec("torch") is not None:
        versions["torch"] = importlib.metadata.version("torch")
    return versions


def _git_commit() -> str | None:
    repo = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("-dirty" if dirty else "")


def evaluate(method_name: str, options: dict, dataset: Path, out: Path, scenes: str | None = None,
             robots: str | None = None, depth_dir: str = DEPTH_DIR, noise: MaskNoise | None = None,
             masks: str = "given") -> dict:
    """Runs (or resumes) the evaluation and returns the summary it wrote to <out>/summary.json."""
    if masks not in MASKS:
        raise UserError(f"--masks {masks!r}: choose given (the data set's masks) or none (no mask of any kind)")
    if masks == "none" and noise is not None:
        raise UserError("--mask-noise perturbs the masks handed in; with --masks none there are none: leave it out")
    method = build_method(method_name, options)
    if hasattr(method, "given"):
        method.given(masks=masks == "given", depth=depth_dir != NO_DEPTH)
    data, out = Dataset(Path(dataset).resolve()), Path(out)
    dataset, info, opts, split = data.root, data.info, method.options(), data.split
    selected = find_scenes(data, scenes, robots)
    identity = {"method": method_name, "options": opts, "dataset": str(dataset), "depth_dir": depth_dir}
    if noise is not None:  # only when on: runs on exact masks keep the identity they had before the option
        identity["mask_noise"] = noise.describe()
    if masks != "given":  # as mask_noise: runs with the data set's masks keep their identity
        identity["masks"] = masks
    models = {obj_id: load_eval_model(dataset, obj_id) for obj_id in sorted({s.meta.obj_id for s in selected})}
    if hasattr(method, "check"):
        method.check({i: complete_frames(p) for i, p in data.scene_dirs().items()}, data.split_dir)
    _claim(out, identity)
    fingerprints = {s.scene_id: scene_fingerprint(s, None if depth_dir == NO_DEPTH else depth_dir,
                                                  models[s.meta.obj_id].sha256,
                                                  _method_inputs(method, s), QUERY_RULE) for s in selected}
    todo, rescore, said = [], [], {}
    for scene in selected:
        changed, scoring_only = _stale(out, scene, fingerprints[scene.scene_id])
        if changed is not None:
            (rescore if scoring_only else todo).append(scene)
        if changed:
            said.setdefault(("; ".join(changed), scoring_only), []).append(scene.scene_id)
    for (changed, scoring_only), ids in said.items():
        how = ("stored estimates are scored again" if scoring_only else "run and scored again")
        print(f"eval: {_scene_ids(ids)}: {changed} changed since the last scoring; {how}", file=sys.stderr)
    for scene in rescore:
        errors = rescore_scene(out, scene, models[scene.meta.obj_id])
        _store_scene(out, scene.scene_id, fingerprints[scene.scene_id], errors)
    bar = tqdm(total=sum(len(s.im_ids) for s in selected), unit="frame", desc=f"eval {method_name}",
               initial=sum(len(s.im_ids) for s in selected) - sum(len(s.im_ids) for s in todo))
    try:
        for scene in todo:
            results, errors = run_scene(method, scene, depth_dir, models[scene.meta.obj_id], bar, noise, masks, out)
            _store_scene(out, scene.scene_id, fingerprints[scene.scene_id], errors, results)
    except BaseException:
        bar.leave = False
        raise
    finally:
        bar.close()

    all_results, all_errors = [], []
    for scene in selected:
        results_csv, errors_csv, _ = _scene_files(out, scene.scene_id)
        all_results.extend(sorted(read_results(results_csv).values(), key=lambda r: r.im_id))
        all_errors.extend(read_errors(errors_csv))
    write_results(out / "results.csv", all_results)
    bop_name = f"{method_name.replace('_', '-')}_{info.get('name', 'syneepose')}-{split}.csv"
    write_atomic(out / bop_name, (out / "results.csv").read_bytes())
    write_errors(out / "errors.csv", all_errors)
    summary = {
        "method": method_name, "options": opts, "backbone": opts.get("backbone"), "variant": opts.get("variant"),
        "dataset": {"path": str(dataset), "preset": info.get("preset"), "split": split,
                    "scenes": [s.scene_id for s in selected], "depth_dir": depth_dir,
                    "mask_noise": None if noise is None else noise.describe()},
        "bop_results": bop_name,
        **summarise(all_errors),
        "model_points": {
            str(obj_id): {"n_vertices": len(m.vertices), "n_query": m.n_query, "subsampled": m.subsampled,
                          "sha256": m.sha256} for obj_id, m in models.items()},
        "model_points_rule": QUERY_RULE_TEXT,
        "versions": _versions(),
        "git_commit": _git_commit(),
    }
    write_atomic(out / "summary.json", json.dumps(summary, indent=2).encode())
    return summary


def add_flags(group, options: type) -> None:
    """One flag per field of a method's `Options`. A flag not given stays out of the namespace, so the
    declaration's default applies and the options a user gave are told apart from the defaults."""
    hints = typing.get_type_hints(options)
    for field in dataclasses.fields(options):
        kind, text, choices = hints[field.name], field.metadata.get("help", ""), field.metadata.get("choices")
        if required(field):
            text += " (required)"
        elif kind is not bool and field.default not in (None, dataclasses.MISSING):
            text += f" (default: {field.default})"
        if kind is bool:
            group.add_argument(flag(field.name), action="store_const", const=True, default=argparse.SUPPRESS,
                               help=text)
        else:
            metavar = "{" + ",".join(map(str, choices)) + "}" if choices else None
            group.add_argument(flag(field.name), type=_parsed_as(kind), metavar=metavar, default=argparse.SUPPRESS,
                               help=text)


def _parsed_as(hint) -> type:
    """The type a flag's text becomes: the annotation, or the one type beside None in `T | None`."""
    kinds = [k for k in typing.get_args(hint) if k is not type(None)]
    return kinds[0] if kinds else hint


def methods_help() -> str:
    """Every method's flags, grouped per method; a method that cannot be loaded says why in its place."""
    sections = []
    for name in known_methods():
        try:
            cls = get_method(name)
        except UserError as exc:
            sections.append(f"--method {name}:\n  {exc}\n")
            continue
        parser = argparse.ArgumentParser(add_help=False, usage=argparse.SUPPRESS)
        none = "takes no options" if not dataclasses.fields(cls.Options) else None
        add_flags(parser.add_argument_group(f"--method {name}", none), cls.Options)
        sections.append(parser.format_help())
    return "\n".join(sections)


class _Help(argparse.Action):
    """-h lists the methods' options too; it loads every method, which a run does not."""

    def __init__(self, option_strings, dest, help=None):
        super().__init__(option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        parser.epilog = methods_help()
        parser.print_help()
        parser.exit()


def method_options(parser: argparse.ArgumentParser, argv, name: str) -> dict:
    """The options given on the command line for method `name` (field -> value); a flag it does not take is
    one line that names the flags it does."""
    cls = get_method(name)
    add_flags(parser.add_argument_group(f"--method {name}"), cls.Options)
    args, unknown = parser.parse_known_args(argv)
    for token in unknown:
        if token.startswith("--"):
            raise UserError(f"method {name!r} does not take {token.split('=')[0]}; it takes {takes(cls)}")
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    return {f.name: getattr(args, f.name) for f in dataclasses.fields(cls.Options) if hasattr(args, f.name)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m eval.run", description=__doc__, add_help=False,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-h", "--help", action=_Help, help="show this help, with every method's options, and exit")
    parser.add_argument("--method", required=True, help=f"{', '.join(known_methods())} (their options below)")
    parser.add_argument("--dataset", required=True, help="BOP data set root (holds dataset_info.json, models/)")
    parser.add_argument("--out", required=True, help="result folder (resumed if it holds the same run)")
    parser.add_argument("--scenes", help="comma-separated scene ids (default: all)")
    parser.add_argument("--robots", help="comma-separated ARM+EE configurations (default: all)")
    parser.add_argument("--depth-dir", default=DEPTH_DIR, help="depth folder of each scene (e.g. depth_gt), or none: "
                        "the method sees no depth (an RGB camera)")
    parser.add_argument("--masks", default="given", choices=MASKS, help="given (the data set's masks, default; "
                        "--mask-noise perturbs them) or none: the method gets no mask of any kind")
    parser.add_argument("--mask-noise", default="none", help="none (the data set's exact masks, default) or sam: "
                        "masks perturbed as a segmenter's (boundary shifted 1-4 px, false blobs, holes; our model)")
    parser.add_argument("--mask-seed", type=int, default=0, help="seed of the mask perturbation (default 0)")
    args, _ = parser.parse_known_args(argv)  # the method's flags are known once the method is

    def action() -> str:
        options = method_options(parser, argv, args.method)
        summary = evaluate(args.method, options, Path(args.dataset), Path(args.out), args.scenes, args.robots,
                           args.depth_dir, mask_noise(args.mask_noise, args.mask_seed), args.masks)
        avg = summary["average"]
        return (f"eval: {summary['n_frames']} frames, {summary['n_failures']} failures; AUC@1cm ADD "
                f"{avg['add@1cm']:.2f} ADD-S {avg['adds@1cm']:.2f} (mean over end-effectors); {args.out}/summary.json")

    return run_command(action)


if __name__ == "__main__":
    sys.exit(main())
