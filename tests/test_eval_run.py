"""The runner end to end on a tiny synthetic BOP set (written with SceneWriter, no rendering): ground-truth
results score 100, a known 3 mm offset scores its closed form, runs resume per scene, and user mistakes
exit 2 with one `error:` line."""

import json
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import kernel.bop
import kernel.dataset
from eval import methods, run
from eval.bop_results import HEADER, read_results
from eval.methods import option, register
from eval.methods.base import Estimate
from eval.metrics import WORKSPACE_POINTS, calibration_error
from eval.model_points import MAX_QUERY
from eval.records import read_errors
from kernel.bop import Frame, SceneMeta, SceneWriter, read_frame, read_scene
from kernel.cli import DEBUG_ENV, run_command
from kernel.errors import UserError
from kernel.files import write_png
from kernel.transforms import make_T

H, W, FRAMES = 12, 16, 4
# scene id -> (arm, end-effector, obj_id)
SCENES = {0: ("ur5e", "robotiq_2f85", 2), 1: ("panda", "kinova_3f", 4)}
OBJ_IDS = list(range(1, 7))
REPO = Path(__file__).resolve().parents[1]


def make_dataset(root: Path, assets: Path, sensor_and_parts: bool = False) -> Path:
    """Two scenes of four frames: random images, a known camera-to-base pose, T_cam_ee = T_cam_base T_base_ee.
    `sensor_and_parts`: a stereo sensor's depth beside the exact one and the robot's part masks, as renders
    with `--depth stereo` write them."""
    rng = np.random.default_rng(0)
    for models in ("models", "models_eval"):
        shutil.copytree(assets / models, root / models, ignore=shutil.ignore_patterns(".*"))
    (root / "dataset_info.json").write_text(json.dumps({"preset": "synthetic", "split": "test", "name": "syneepose"}))
    for scene_id, (arm, ee, obj_id) in SCENES.items():
        T_cam_base = make_T(Rotation.from_euler("xyz", [-2.0, 0.1, 0.3 * scene_id]).as_matrix(), [0.1, 0.2, 1.5])
        extras = {"depth_sensor": {"mode": "stereo", "profile": {}}, "links": ["link", "ee"]} if sensor_and_parts else {}
        meta = SceneMeta(obj_id=obj_id, arm=arm, end_effector=ee, joint_names=[f"j{i}" for i in range(6)],
                         T_cam_base=T_cam_base, **extras)
        writer = SceneWriter(root / "test" / f"{scene_id:06d}", meta, OBJ_IDS)
        for im_id in range(FRAMES):
            T_base_ee = make_T(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.4, 0.4, 3) + [0, 0, 0.5])
            mask = np.zeros((H, W), bool)
            mask[3:9, 4:12] = True
            depth = rng.uniform(0.5, 2.0, (H, W))
            parts = {"depth_gt": depth, "link_ids": (1 + mask).astype(np.uint8)} if sensor_and_parts else {}
            writer.write(Frame(im_id=im_id, rgb=rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
                               depth=depth, mask=mask, mask_visib=mask,
                               K=np.array([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]]), T_cam_ee=T_cam_base @ T_base_ee,
                               joint_positions=rng.uniform(-2, 2, 6), T_base_ee=T_base_ee, **parts))
    return root


def gt_csv(path: Path, dataset: Path, offset_mm=(0.0, 0.0, 0.0), drop=()) -> Path:
    """The ground truth as a BOP results CSV, copied from scene_gt.json in its own units (mm) so that it reads
    back bit for bit; translated by `offset_mm` in the camera frame and without the frames `drop`."""
    lines = [HEADER]
    for scene_id in SCENES:
        scene_gt = json.loads((dataset / "test" / f"{scene_id:06d}" / "scene_gt.json").read_text())
        for im_id, (gt,) in sorted(scene_gt.items(), key=lambda item: int(item[0])):
            if (scene_id, int(im_id)) not in drop:
                t = np.add(gt["cam_t_m2c"], offset_mm)
                lines.append(f"{scene_id},{im_id},{gt['obj_id']},0.9,{' '.join(map(repr, gt['cam_R_m2c']))},"
                             f"{' '.join(map(repr, t.tolist()))},0.05")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, assets) -> Path:
    return make_dataset(tmp_path_factory.mktemp("synthetic"), assets)


def _eval(dataset, out, csv, *extra) -> int:
    return run.main(["--method", "bop-csv", "--dataset", str(dataset), "--out", str(out), "--results", str(csv),
                     "--name", "Oracle", *extra])


def _one_error_line(stderr: str) -> str:
    lines = [line for line in stderr.replace("\r", "\n").splitlines() if line.strip()]
    assert "Traceback" not in stderr and lines[-1].startswith("error: ")
    assert sum(line.startswith("error:") for line in lines) == 1
    return lines[-1]


def test_ground_truth_scores_100(dataset, tmp_path):
    csv, out = gt_csv(tmp_path / "results.csv", dataset), tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "eval.run", "--method", "bop-csv", "--dataset", str(dataset),
                           "--out", str(out), "--results", str(csv), "--name", "Oracle"],
                          capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    for acc in (summary["average"], *summary["per_end_effector"].values(), *summary["per_config"].values()):
        assert acc["add@1cm"] == acc["adds@1cm"] == acc["add@2cm"] == acc["adds@2cm"] == 100.0
    assert (summary["n_frames"], summary["n_failures"]) == (8, 0)
    assert sorted(summary["per_end_effector"]) == ["kinova_3f", "robotiq_2f85"]
    assert sorted(summary["per_config"]) == ["panda+kinova_3f", "ur5e+robotiq_2f85"]
    assert summary["method"] == "bop-csv" and summary["options"]["name"] == "Oracle"
    assert summary["dataset"]["preset"] == "synthetic" and summary["ms_per_frame"] == pytest.approx(50.0)
    assert summary["calibration"] == {"n_frames": 0, "trans_mm": None, "rot_deg": None, "points_mm": None,
                                      "frame_15": None}
    assert {"numpy", "scipy", "cv2"} <= set(summary["versions"])
    points = summary["model_points"]["2"]
    n_vertices = len(trimesh.load(dataset / "models_eval" / "obj_000002.ply", process=False).vertices)
    assert points["n_vertices"] == n_vertices and 0.9 * MAX_QUERY < points["n_query"] <= MAX_QUERY
    assert read_results(out / "results.csv").keys() == read_results(csv).keys()
    # The BOP toolkit finds results by their name: METHOD_DATASET-SPLIT.csv.
    assert summary["bop_results"] == "bop-csv_syneepose-test.csv"
    assert (out / "bop-csv_syneepose-test.csv").read_bytes() == (out / "results.csv").read_bytes()


def test_offset_of_3mm_scores_its_closed_form_and_missing_frames_fail(dataset, tmp_path):
    csv = gt_csv(tmp_path / "results.csv", dataset, offset_mm=(0.0, 3.0, 0.0), drop={(0, 1)})
    assert _eval(dataset, tmp_path / "out", csv) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    kinova, gripper = summary["per_end_effector"]["kinova_3f"], summary["per_end_effector"]["robotiq_2f85"]
    # ADD = 3 mm on every estimated frame: AUC = (10 - 3) / 10 at 1 cm, (20 - 3) / 20 at 2 cm.
    assert kinova["add@1cm"] == pytest.approx(70.0, abs=0.1) and kinova["add@2cm"] == pytest.approx(85.0, abs=0.1)
    assert gripper["add@1cm"] == pytest.approx(70.0 * 3 / 4, abs=0.1)  # one frame of four has no estimate
    assert summary["average"]["add@1cm"] == pytest.approx((70.0 + 52.5) / 2, abs=0.1)
    assert kinova["adds@1cm"] >= kinova["add@1cm"]
    assert (summary["n_failures"], gripper["n_failures"]) == (1, 1)
    rows = {(r.scene_id, r.im_id): r for r in read_errors(tmp_path / "out" / "errors.csv")}
    failed = rows[(0, 1)]
    assert np.isinf(failed.add_m) and np.isinf(failed.adds_m) and np.isnan(failed.rot_err_deg)
    assert np.isnan(failed.score) and failed.time_s == -1.0
    for key, r in rows.items():
        if key != (0, 1):
            assert r.add_m == pytest.approx(0.003, abs=1e-9) and r.trans_err_mm == pytest.approx(3.0, abs=1e-6)
            assert r.rot_err_deg == pytest.approx(0.0, abs=1e-6) and r.score == 0.9
    assert len(read_results(tmp_path / "out" / "results.csv")) == 7


def _stamps(out: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in (out / "scenes").iterdir()}


def _per_ee(out: Path) -> dict[str, float]:
    per_ee = json.loads((out / "summary.json").read_text())["per_end_effector"]
    return {ee: round(acc["add@1cm"], 1) for ee, acc in per_ee.items()}


def test_resume_skips_complete_scenes_and_never_reuses_a_stale_one(dataset, tmp_path, capsys):
    data, out = tmp_path / "data", tmp_path / "out"
    shutil.copytree(dataset, data)
    csv = gt_csv(tmp_path / "results.csv", data, offset_mm=(3.0, 0.0, 0.0))
    assert _eval(data, out, csv) == 0
    stamps = _stamps(out)
    # Same run, same inputs: nothing is recomputed.
    assert _eval(data, out, csv) == 0
    assert _stamps(out) == stamps and _per_ee(out) == {"kinova_3f": 70.0, "robotiq_2f85": 70.0}
    # A scene without its errors file is run again, and only that one.
    (out / "scenes" / "000001.errors.csv").unlink()
    assert _eval(data, out, csv) == 0
    assert sorted({n.split(".")[0] for n in stamps if _stamps(out)[n] != stamps[n]}) == ["000001"]
    # The method's input changed (the CSV now holds the ground truth): every scene is scored again, and said so.
    gt_csv(csv, data)
    capsys.readouterr()
    assert _eval(data, out, csv) == 0
    assert _per_ee(out) == {"kinova_3f": 100.0, "robotiq_2f85": 100.0}
    assert ("scenes 0-1: method input results.csv changed since the last scoring; run and scored again"
            in capsys.readouterr().err)
    # A re-written image of scene 1 (same bytes, new file) re-scores scene 1 only.
    stamps = _stamps(out)
    image = data / "test" / "000001" / "rgb" / "000002.png"
    image.write_bytes(image.read_bytes())
    assert _eval(data, out, csv) == 0
    rescored = sorted({n.split(".")[0] for n in stamps if _stamps(out)[n] != stamps[n]})
    assert rescored == ["000001"] and "rgb/000002.png" in capsys.readouterr().err
    # So does a changed ground truth (scene JSON) and a changed evaluation model.
    stamps = _stamps(out)
    scene_gt = data / "test" / "000000" / "scene_gt.json"
    scene_gt.write_text(scene_gt.read_text() + "\n")
    assert _eval(data, out, csv) == 0
    assert sorted({n.split(".")[0] for n in stamps if _stamps(out)[n] != stamps[n]}) == ["000000"]
    assert "scene_gt.json" in capsys.readouterr().err
    # A changed evaluation model scores scene 1's stored estimates again without running the method: its
    # results file stays as it was, its errors move and equal a fresh run's into another folder.
    gt_csv(csv, data, offset_mm=(3.0, 0.0, 0.0))
    assert _eval(data, out, csv) == 0
    stamps, before = _stamps(out), read_errors(out / "scenes" / "000001.errors.csv")
    ply = data / "models_eval" / "obj_000004.ply"
    mesh = trimesh.load(ply, process=False)
    mesh.vertices *= 1.5
    ply.write_bytes(trimesh.exchange.ply.export_ply(mesh))
    capsys.readouterr()
    assert _eval(data, out, csv) == 0
    assert ("scene 1: the evaluation model (models_eval/) changed since the last scoring; stored estimates "
            "are scored again") in capsys.readouterr().err
    now = _stamps(out)
    assert sorted(n for n in stamps if now[n] != stamps[n]) == ["000001.errors.csv", "000001.fingerprint.json"]
    after = read_errors(out / "scenes" / "000001.errors.csv")
    assert all(a.adds_m != b.adds_m for a, b in zip(after, before))
    assert _eval(data, tmp_path / "fresh", csv) == 0
    fresh = read_errors(tmp_path / "fresh" / "scenes" / "000001.errors.csv")
    assert [(r.im_id, r.add_m, r.adds_m) for r in after] == [(r.im_id, r.add_m, r.adds_m) for r in fresh]


def test_the_fingerprint_holds_every_file_the_run_reads(tmp_path, assets, monkeypatch, capsys):
    """Every image the runner opens for a scene (a stereo scene with the robot's part masks, scored on its exact
    depth) is in that scene's fingerprint, so a rewritten part mask, exact depth or amodal mask runs the scene
    again; the list comes from the kernel's layout, not a second spelling of folder names."""
    data = make_dataset(tmp_path / "data", assets, sensor_and_parts=True)
    csv = gt_csv(tmp_path / "results.csv", data)
    opened = []
    for module in (kernel.bop, kernel.dataset):
        real = module.read_png
        monkeypatch.setattr(module, "read_png", lambda path, *a, real=real, **k: opened.append(Path(path)) or real(path, *a, **k))
    out = tmp_path / "out"
    assert _eval(data, out, csv, "--depth-dir", "depth_gt") == 0
    scene = data / "test" / "000001"
    fingerprint = json.loads((out / "scenes" / "000001.fingerprint.json").read_text())
    read = {p.relative_to(scene).as_posix() for p in opened if scene in p.parents}
    assert {"robot_mask_visib", "depth_gt", "mask", "mask_visib", "rgb", "depth"} == {r.split("/")[0] for r in read}
    assert read <= set(fingerprint["images"])
    for changed in ("robot_mask_visib/000002.png", "depth_gt/000001.png", "mask/000003_000000.png"):
        stamps = _stamps(out)
        (scene / changed).write_bytes((scene / changed).read_bytes())
        capsys.readouterr()
        assert _eval(data, out, csv, "--depth-dir", "depth_gt") == 0
        assert sorted({n.split(".")[0] for n in stamps if _stamps(out)[n] != stamps[n]}) == ["000001"]
        assert changed in capsys.readouterr().err


def test_the_robot_outline_fingerprints_the_arm_urdf_and_its_link_meshes(tiny_dataset):
    """`--silhouette robot` reads the arm's URDF and link meshes: they are the method's inputs, so a changed
    robot model runs the scenes again."""
    from eval.methods.feepe import Feepe, FeepeFlags, arm_models, link_mesh_paths

    scene = sorted((tiny_dataset / "test").iterdir())[0]
    meta, _ = read_scene(scene)
    method = Feepe(FeepeFlags(refine="silhouette", silhouette="robot"))
    inputs = method.inputs(meta, scene)
    robot, links, _ = arm_models(meta)
    meshes = [p for name in links for p in link_mesh_paths(robot, name)]
    assert robot.urdf in inputs and meshes and set(meshes) <= set(inputs) and all(p.exists() for p in inputs)
    assert not any(p.suffix == ".urdf" for p in Feepe(FeepeFlags(refine="silhouette")).inputs(meta, scene))


def test_scene_and_robot_selection(dataset, tmp_path):
    csv = gt_csv(tmp_path / "results.csv", dataset)
    assert _eval(dataset, tmp_path / "a", csv, "--scenes", "1") == 0
    assert list(json.loads((tmp_path / "a" / "summary.json").read_text())["per_end_effector"]) == ["kinova_3f"]
    assert _eval(dataset, tmp_path / "b", csv, "--robots", "ur5e+robotiq_2f85") == 0
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["dataset"]["scenes"] == [0]


@pytest.mark.parametrize("case, message", [
    ("missing scene", "scene 7 is not in"),
    ("bad line", "results.csv:3: 6 columns"),
    ("scene not in data set", "results.csv:2: scene 5 is not in the data set"),
    ("unknown method", "unknown method 'nope'; known methods: bop-csv, feepe"),
    ("option the method lacks", "method 'bop-csv' does not take --variant; it takes --results, --name"),
    ("option missing", "method 'bop-csv' needs --results"),
    ("other run in out", "holds a run with other options"),
    ("depth dir missing", "depth_gt/000000.png: missing"),
])
def test_user_mistakes_exit_2_with_one_line(dataset, tmp_path, capsys, case, message):
    csv, out = gt_csv(tmp_path / "results.csv", dataset), tmp_path / "out"
    args = ["--method", "bop-csv", "--dataset", str(dataset), "--out", str(out), "--results", str(csv),
            "--name", "Oracle"]
    if case == "missing scene":
        args += ["--scenes", "0,7"]
    elif case == "bad line":
        lines = csv.read_text().splitlines()
        csv.write_text("\n".join([*lines[:2], lines[2].rsplit(",", 1)[0], *lines[3:]]) + "\n")
    elif case == "scene not in data set":
        lines = csv.read_text().splitlines()
        csv.write_text("\n".join([lines[0], "5" + lines[1][1:], *lines[2:]]) + "\n")
    elif case == "unknown method":
        args[1] = "nope"
    elif case == "option the method lacks":
        args += ["--variant", "A"]
    elif case == "option missing":
        args = args[:6] + ["--name", "Oracle"]
    elif case == "other run in out":
        assert run.main(args) == 0
        capsys.readouterr()
        args[-1] = "Another label"
    elif case == "depth dir missing":
        args += ["--depth-dir", "depth_gt"]
    assert run.main(args) == 2
    assert message in _one_error_line(capsys.readouterr().err)


def test_bad_csv_through_the_command_line(dataset, tmp_path):
    csv = tmp_path / "results.csv"
    csv.write_text("scene_id,im_id,obj_id,score,R,t,time\n0,0,2,0.9,1 0 0 0 1 0 0 0 1,0 0 x,0.1\n")
    proc = subprocess.run([sys.executable, "-m", "eval.run", "--method", "bop-csv", "--dataset", str(dataset),
                           "--out", str(tmp_path / "out"), "--results", str(csv), "--name", "Broken"],
                          capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 2
    assert f"{csv}:2: not a number" in _one_error_line(proc.stderr)


@dataclass(frozen=True)
class ProbeFlags:
    variant: str = option("D", "recorded as the run's variant")
    backbone: str = option("none", "recorded as the run's backbone")


@register("test-probe")
class Probe:
    """Records what the runner hands a method; answers the depth it saw as a pose (for --depth-dir)."""

    Options = ProbeFlags
    seen: list = []

    def __init__(self, flags: ProbeFlags):
        self.variant, self.backbone = flags.variant, flags.backbone

    def options(self) -> dict:
        return {"variant": self.variant, "backbone": self.backbone}

    def start_scene(self, meta, scene_dir):
        Probe.seen.append(("scene", Path(scene_dir).name, meta.T_cam_base.copy()))

    def estimate(self, obs):
        Probe.seen.append(("frame", obs))
        return Estimate(T_cam_ee=None, score=0.0, time_s=-1.0, T_cam_base=make_T(t=[0.0, 0.0, obs.depth[0, 0]]))


def test_methods_get_observations_in_order_without_ground_truth(dataset, tmp_path):
    """Options reach the constructor; scenes and frames come in order; --depth-dir swaps the depth folder."""
    data = tmp_path / "data"
    shutil.copytree(dataset, data)
    for scene_id in SCENES:
        scene = data / "test" / f"{scene_id:06d}"
        (scene / "depth_gt").mkdir()
        for im_id in range(FRAMES):
            write_png(scene / "depth_gt" / f"{im_id:06d}.png", np.full((H, W), 5000 + im_id, np.uint16))
    Probe.seen.clear()
    assert run.main(["--method", "test-probe", "--dataset", str(data), "--out", str(tmp_path / "out"),
                     "--variant", "B", "--depth-dir", "depth_gt"]) == 0
    assert [item[1] for item in Probe.seen if item[0] == "scene"] == ["000000", "000001"]
    assert all(np.isnan(item[2]).all() for item in Probe.seen if item[0] == "scene")
    observations = [item[1] for item in Probe.seen if item[0] == "frame"]
    assert [o.im_id for o in observations] == [0, 1, 2, 3] * 2
    assert not hasattr(observations[0], "T_cam_ee")
    frame = read_frame(data / "test" / "000000", 2)
    assert np.array_equal(observations[2].mask, frame.mask_visib) and np.array_equal(observations[2].rgb, frame.rgb)
    assert observations[2].depth[0, 0] == pytest.approx(0.5002)  # 5002 x depth_scale 0.1 mm
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert (summary["variant"], summary["backbone"], summary["n_failures"]) == ("B", "none", 8)
    assert summary["average"]["add@1cm"] == 0.0 and summary["calibration"]["n_frames"] == 8
    # the calibration error at the workspace points, per frame, as eval.metrics computes it
    rows = read_errors(tmp_path / "out" / "errors.csv")
    for r in rows:
        meta, _ = read_scene(data / "test" / f"{r.scene_id:06d}")
        T_est = make_T(t=[0.0, 0.0, 0.5 + 1e-4 * r.im_id])
        expected = calibration_error(T_est, meta.T_cam_base, WORKSPACE_POINTS).points_mm.mean()
        assert r.calib_points_mm == pytest.approx(expected, rel=1e-3) and r.calib_points_mm > 0


@pytest.fixture
def method_files(tmp_path, monkeypatch):
    """A folder whose modules count as modules of eval/methods/; what they register is forgotten afterwards."""
    folder = tmp_path / "methods"
    folder.mkdir()
    monkeypatch.setattr(methods, "__path__", [*methods.__path__, str(folder)])
    yield folder
    ours = {f"eval.methods.{p.stem}" for p in folder.glob("*.py")}
    for name in [n for n, cls in methods._REGISTRY.items() if cls.__module__ in ours]:
        del methods._REGISTRY[name]
    for module in ours:
        sys.modules.pop(module, None)


def test_registry_names_a_broken_method_module(method_files, capsys):
    """A method module that cannot be imported breaks only itself, with an error that names it."""
    (method_files / "broken.py").write_text("raise RuntimeError('no weights configured')\n")
    (method_files / "needy.py").write_text("import a_package_nobody_has\n")
    (method_files / "misnamed.py").write_text("")
    with pytest.raises(UserError, match="method 'broken' failed to load: eval.methods.broken: RuntimeError: no w"):
        methods.get_method("broken")
    with pytest.raises(UserError, match="method 'needy' failed to load: eval.methods.needy: .*a_package_nobody_has"):
        methods.get_method("needy")
    with pytest.raises(UserError, match=r"method 'misnamed': eval.methods.misnamed registers no method of that name"):
        methods.get_method("misnamed")
    with pytest.raises(UserError, match="unknown method 'ghost'; known methods: bop-csv, broken, feepe, handeye"):
        methods.get_method("ghost")
    assert methods.get_method("bop-csv").name == "bop-csv"
    with pytest.raises(SystemExit) as exit_:
        run.main(["--help"])
    assert exit_.value.code == 0
    help_text = " ".join(capsys.readouterr().out.split())
    assert "--method broken: method 'broken' failed to load: eval.methods.broken: RuntimeError" in help_text
    assert "--method feepe: --variant {A,B,C,D} ablation variant (default: D)" in help_text
    assert "--method handeye: --hand-eye {tsai,park,horaud,andreff,daniilidis}" in help_text


def test_a_broken_method_is_one_line_and_its_import_traceback_on_the_debug_switch(method_files, capsys, monkeypatch):
    (method_files / "needy.py").write_text("import a_package_nobody_has\n")
    monkeypatch.delenv(DEBUG_ENV, raising=False)
    assert run_command(lambda: methods.get_method("needy")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and f"({DEBUG_ENV}=1 shows the traceback)" in err
    monkeypatch.setenv(DEBUG_ENV, "1")
    sys.modules.pop("eval.methods.needy", None)
    assert run_command(lambda: methods.get_method("needy")) == 2
    err = capsys.readouterr().err
    assert 'needy.py", line 1, in <module>' in err
    assert "ModuleNotFoundError: No module named 'a_package_nobody_has'" in err
    assert err.splitlines()[-1].startswith("error: method 'needy' failed to load: eval.methods.needy: ModuleNotFound")


TOY_METHOD = '''"""`toy-offset`: the ground truth moved along the camera's x axis, a method in one file."""

from dataclasses import dataclass

from eval.methods import option, register
from eval.methods.base import Estimate
from kernel.bop import read_gt_poses


@dataclass(frozen=True)
class ToyFlags:
    offset_mm: float = option(0.0, "how far the estimates are moved", within=(0.0, 100.0))


@register("toy-offset")
class ToyOffset:
    Options = ToyFlags

    def __init__(self, flags: ToyFlags):
        self.offset_mm, self.gt = flags.offset_mm, {}

    def options(self) -> dict:
        return {"offset_mm": self.offset_mm}

    def start_scene(self, meta, scene_dir):
        self.gt = read_gt_poses(scene_dir)

    def estimate(self, obs):
        T = self.gt[obs.im_id].copy()
        T[0, 3] += self.offset_mm / 1000.0
        return Estimate(T_cam_ee=T, score=1.0, time_s=0.0)
'''


def test_a_new_method_is_one_file_with_its_own_flags(dataset, tmp_path, method_files, capsys):
    """Dropped into eval/methods/, a module is `--method` by its name, and its option dataclass makes its flags,
    their checks and their help; nothing else is edited."""
    (method_files / "toy_offset.py").write_text(TOY_METHOD)
    common = ["--method", "toy-offset", "--dataset", str(dataset)]
    assert run.main([*common, "--out", str(tmp_path / "out"), "--offset-mm", "3"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["method"] == "toy-offset" and summary["options"] == {"offset_mm": 3.0}
    assert summary["average"]["add@1cm"] == pytest.approx(70.0, abs=0.1)  # ADD = 3 mm on every frame
    for argv, message in (
            ([*common, "--offset-mm", "500"], "--offset-mm 500.0: must lie in 0.0..100.0"),
            ([*common, "--k-r", "3"], "method 'toy-offset' does not take --k-r; it takes --offset-mm"),
            (["--method", "bop-csv", "--dataset", str(dataset), "--results", "x.csv", "--name", "X", "--offset-mm",
              "3"], "method 'bop-csv' does not take --offset-mm; it takes --results, --name")):
        assert run.main([*argv, "--out", str(tmp_path / "refused")]) == 2
        assert message in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "refused").exists()
    with pytest.raises(SystemExit):
        run.main(["--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "--method toy-offset: --offset-mm OFFSET_MM how far the estimates are moved (default: 0.0)" in help_text


def test_mask_noise_reaches_the_method_seeded_and_claims_the_out_folder(dataset, tmp_path, capsys):
    """--mask-noise hands the method perturbed masks, the same on a rerun, and a folder scored on exact masks
    is not resumed with perturbed ones."""
    masks = []
    for out in ("a", "b"):
        Probe.seen.clear()
        assert run.main(["--method", "test-probe", "--dataset", str(dataset), "--out", str(tmp_path / out),
                         "--mask-noise", "sam", "--mask-seed", "2"]) == 0
        masks.append([item[1].mask for item in Probe.seen if item[0] == "frame"])
    exact = read_frame(dataset / "test" / "000000", 0).mask_visib
    assert any(not np.array_equal(m, exact) for m in masks[0])
    assert all(np.array_equal(a, b) for a, b in zip(*masks))
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["dataset"]["mask_noise"]["seed"] == 2
    capsys.readouterr()
    assert run.main(["--method", "test-probe", "--dataset", str(dataset), "--out", str(tmp_path / "a")]) == 2
    assert "holds a run with other mask_noise" in _one_error_line(capsys.readouterr().err)
    assert run.main(["--method", "test-probe", "--dataset", str(dataset), "--out", str(tmp_path / "c"),
                     "--mask-noise", "blur"]) == 2
    assert "--mask-noise 'blur' unknown" in _one_error_line(capsys.readouterr().err)


def test_masks_none_hands_in_no_mask_and_scores_the_masks_the_method_made(tiny_dataset, tmp_path, capsys):
    """`--masks none`: FEEPE gets no mask of any kind, finds and segments the robot itself; its masks are written
    as a BOP scene keeps them and scored against the true visible masks (errors.csv, summary.json)."""
    out = tmp_path / "none"
    assert run.main(["--method", "feepe", "--dataset", str(tiny_dataset), "--masks", "none", "--robots",
                     "ur5e+robotiq_2f85", "--out", str(out)]) == 0
    [errors] = list((out / "scenes").glob("*.errors.csv"))
    rows = read_errors(errors)
    scene_id = rows[0].scene_id
    masks = run.own_masks_dir(out, scene_id)
    assert all(r.ee_mask_iou > 0.8 and r.robot_mask_iou > 0.9 for r in rows), [(r.ee_mask_iou, r.robot_mask_iou) for r in rows]
    assert sorted(p.name for p in (masks / "mask_visib").iterdir()) == [f"{r.im_id:06d}_000000.png" for r in rows]
    assert len(list((masks / "robot_mask").iterdir())) == len(rows)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["own_masks"]["n_frames"] == len(rows) and summary["own_masks"]["robot_iou"]["median"] > 0.9
    assert json.loads((out / "run.json").read_text())["masks"] == "none"
    for argv, words in ((["--method", "feepe", "--masks", "none", "--mask-noise", "sam"], "--mask-noise"),
                        (["--method", "ppf", "--masks", "none"], "needs --masks given")):
        capsys.readouterr()
        assert run.main([*argv, "--dataset", str(tiny_dataset), "--out", str(tmp_path / "refused")]) == 2
        assert words in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "refused").exists()


def test_given_masks_as_a_prior_take_the_robots_outline_and_are_part_of_the_runs_identity():
    from eval.methods.feepe import Feepe, FeepeFlags

    prior, truth = Feepe(FeepeFlags(given_masks="prior")), Feepe(FeepeFlags())
    assert (prior.opts.silhouette, prior.opts.refine, prior.opts.given_masks) == ("robot", "silhouette", "prior")
    assert prior.options()["given_masks"] == "prior" and prior.options()["estimator"]["given_masks"] == "prior"
    assert "given_masks" not in truth.options() and "given_masks" not in truth.options()["estimator"]
    prior.given(masks=True, depth=True)
    truth.given(masks=True, depth=True)
    assert prior.opts.refine == "silhouette+depth" and (truth.opts.refine, truth.opts.silhouette) == ("none", "ee")
    for depth, refine in ((True, "silhouette+depth"), (False, "silhouette")):  # no mask: depth where there is depth
        none = Feepe(FeepeFlags())
        none.given(masks=False, depth=depth)
        assert (none.opts.silhouette, none.opts.refine) == ("robot", refine)
    chosen = Feepe(FeepeFlags(refine="silhouette"))
    chosen.given(masks=False, depth=True)
    assert chosen.opts.refine == "silhouette"
