"""The bad-input battery: every mistake a user can make on the command lines (and the preset files they
feed them) ends with exit 2 (1 for a refused file operation), an `error:` line that names the culprit, no
traceback, and nothing written. Called in-process through each CLI's `main`, so an uncaught exception
fails the test as a traceback would.
"""

import json
import shutil
from contextlib import nullcontext
from pathlib import Path

import pytest
import yaml

from eval import overlays, run, tables
from syneepose import __main__ as syneepose_cli
from tests.test_eval_run import gt_csv, make_dataset

MINI = yaml.safe_load(Path("scenes/mini.yaml").read_text())


def _fails(capsys, main, argv, *words, code=2):
    with pytest.raises(SystemExit) if any(w.startswith("usage") for w in words) else nullcontext():
        result = main([str(a) for a in argv])
        assert result == code, capsys.readouterr().err
    err = capsys.readouterr().err
    assert "Traceback" not in err
    line = [ln for ln in err.strip().splitlines() if "error" in ln][-1]
    for word in words:
        if not word.startswith("usage"):
            assert word in line, line
    return line


# --- python -m syneepose render: flags -------------------------------------------------------------------

RENDER = [
    (["--frames", -2], ["--frames -2", "greater than or equal to 1"]),
    (["--frames", 0], ["--frames 0"]),
    (["--samples", -1], ["--samples -1"]),
    (["--samples", 0], ["--samples 0"]),
    (["--samples", 10**6], ["--samples 1000000"]),
    (["--segments", 0], ["--segments 0"]),
    (["--segments", -3], ["--segments -3"]),
    (["--resolution", "100000x100000"], ["--resolution", "8192"]),
    (["--resolution", "0x0"], ["--resolution"]),
    (["--resolution", "7x7"], ["--resolution", "8"]),
    (["--resolution", "64by48"], ["--resolution", "WxH"]),
    (["--resolution", "x"], ["--resolution", "WxH"]),
    (["--resolution=-64x48"], ["--resolution"]),
    (["--seed", -1], ["--seed -1"]),
    (["--workers", 0], ["--workers 0"]),
    (["--workers", 1000], ["--workers 1000"]),
    (["--robots", ","], ["--robots", "no configuration"]),
    (["--robots", "ur5e+robotiq_2f85,ur5e+robotiq_2f85"], ["ur5e+robotiq_2f85 twice"]),
    (["--robots", "ur5e+claw"], ["claw"]),
    (["--robots", "kuka+robotiq_2f85"], ["kuka"]),
    (["--robots", "ur5e"], ["ur5e"]),
    (["--preset", "nosuch"], ["nosuch"]),
    (["--shard", "3/2"], ["--shard"]),
    (["--shard", "a/b"], ["--shard", "i/N"]),
    (["--shard", "0/0"], ["--shard"]),
    (["--shard=-1/2"], ["--shard"]),
    (["--backgrounds", "/nonexistent/folder"], ["--backgrounds", "no .png/.jpg"]),
    (["--hard", "smoke"], ["--hard", "smoke", "occluder, exit, arm_coloured"]),
    (["--hard", "exit,exit"], ["--hard", "exit twice"]),
    (["--depth", "stereo", "--sensor", "nosuch"], ["nosuch"]),
    (["--frames", "2.5"], ["usage", "--frames"]),
    (["--depth", "lidar"], ["usage", "--depth"]),
    (["--device", "tpu"], ["usage", "--device"]),
]


@pytest.mark.parametrize("args,words", RENDER, ids=[" ".join(map(str, a)) for a, _ in RENDER])
def test_render_flag_mistakes(capsys, tmp_path, args, words):
    out = tmp_path / "o"
    _fails(capsys, syneepose_cli.main, ["render", "--out", out, *args], *words)
    assert not out.exists()


# --- preset files ----------------------------------------------------------------------------------------

def _with(path: str, value):
    content = json.loads(json.dumps(MINI))
    *parents, key = path.split(".")
    node = content
    for p in parents:
        node = node[p]
    if value is _DROP:
        del node[key]
    else:
        node[key] = value
    return content


_DROP = object()
PRESETS = [
    (_with("lighting", {}), ["unknown key 'lighting'"]),
    (_with("camera.fov", 60), ["unknown key 'camera.fov'"]),
    (_with("lights.colour", 1), ["unknown key 'lights.colour'"]),
    (_with("camera.hfov_deg", [70, 50]), ["camera.hfov_deg", "inverted"]),
    (_with("camera.hfov_deg", "wide"), ["camera.hfov_deg"]),
    (_with("camera.hfov_deg", [50, 200]), ["camera.hfov_deg.1 = 200"]),
    (_with("camera.distance", [0, 1]), ["camera.distance.0 = 0"]),
    (_with("camera.min_visible", 1.5), ["camera.min_visible = 1.5"]),
    (_with("camera", _DROP), ["missing key 'camera'"]),
    (_with("motion.waypoints", 0), ["motion.waypoints = 0"]),
    (_with("motion.spread", -1), ["motion.spread = -1"]),
    (_with("samples", "16"), ["samples = \"16\""]),
    (_with("frames", 0), ["frames = 0"]),
    (_with("frames", True), ["frames = true"]),
    (_with("resolution", [1, 1]), ["resolution.0 = 1"]),
    (_with("resolution", [640]), ["resolution"]),
    (_with("lights.kinds", ["LASER"]), ["lights.kinds.0 = \"LASER\""]),
    (_with("lights.count", [3, 1]), ["lights.count", "inverted"]),
    (_with("backdrop.kinds", []), ["backdrop.kinds"]),
    (_with("backdrop.walls", [0, 9]), ["backdrop.walls.1 = 9"]),
    (_with("distractors.count", [0, 1, 2]), ["distractors.count"]),
    (_with("render.max_bounces", -1), ["render.max_bounces = -1"]),
    (_with("render.denoise", "yes"), ["render.denoise"]),
    (_with("templates.views", 0), ["templates.views = 0"]),
    (_with("stations", {"max_tilt_deg": 95}), ["stations.max_tilt_deg = 95"]),
    (_with("marker", {"squares": [1, 1]}), ["marker.squares.0 = 1"]),
    ([1, 2, 3], ["not a mapping"]),
]


@pytest.mark.parametrize("content,words", PRESETS, ids=[w[0] for _, w in PRESETS])
def test_preset_mistakes(capsys, tmp_path, content, words):
    preset = tmp_path / "bad.yaml"
    preset.write_text(yaml.safe_dump(content))
    out = tmp_path / "o"
    _fails(capsys, syneepose_cli.main, ["render", "--preset", preset, "--out", out], "bad.yaml", *words)
    assert not out.exists()


@pytest.mark.parametrize("text,word", [("camera: [unclosed\n", "not valid YAML"), ("", "not a mapping"),
                                       ("name: x\nwhen: 2024-01-01\n", "settings are numbers")])
def test_preset_files_that_are_not_presets(capsys, tmp_path, text, word):
    preset = tmp_path / "bad.yaml"
    preset.write_text(text)
    _fails(capsys, syneepose_cli.main, ["render", "--preset", preset, "--out", tmp_path / "o"], "bad.yaml", word)
    assert not (tmp_path / "o").exists()


# --- templates, show, assets -------------------------------------------------------------------------------

OTHERS = [
    (["templates", "--resolution", -32], ["--resolution -32"]),
    (["templates", "--resolution", 100000], ["--resolution 100000"]),
    (["templates", "--views", 0], ["--views 0"]),
    (["templates", "--inplane", -1], ["--inplane -1"]),
    (["templates", "--samples", 0], ["--samples 0"]),
    (["templates", "--ee", ","], ["--ee", "no end-effector"]),
    (["templates", "--ee", "foo"], ["foo"]),
    (["templates", "--ee", "robotiq_2f85,robotiq_2f85"], ["robotiq_2f85 twice"]),
    (["templates", "--workers", 0], ["--workers 0"]),
    (["templates", "--preset", "nosuch"], ["nosuch"]),
    (["assets", "--robots", "ur5e+claw"], ["claw"]),
    (["assets", "--robots", ","], ["--robots"]),
]


def test_render_and_templates_out_naming_a_file(capsys, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("")
    for command in ("render", "templates"):
        _fails(capsys, syneepose_cli.main, [command, "--out", afile], "--out", "is a file")
    assert afile.read_text() == ""


@pytest.mark.parametrize("args,words", OTHERS, ids=[" ".join(map(str, a)) for a, _ in OTHERS])
def test_templates_and_assets_mistakes(capsys, tmp_path, args, words):
    out = tmp_path / "o"
    _fails(capsys, syneepose_cli.main, [*args, "--out", out], *words)
    assert not out.exists()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, assets):
    return make_dataset(tmp_path_factory.mktemp("bad") / "data", assets)


SHOW = [
    (["--width", 100000], ["--width 100000"]),
    (["--width", 0], ["--width 0"]),
    (["--frames", 0], ["--frames 0"]),
    (["--frames", -1], ["--frames -1"]),
    (["--out", "sheet.jpg"], ["give a .png"]),
]


@pytest.mark.parametrize("args,words", SHOW, ids=[" ".join(map(str, a)) for a, _ in SHOW])
def test_show_mistakes(capsys, tmp_path, dataset, args, words):
    args = [tmp_path / a if a == "sheet.jpg" else a for a in args]
    out = [] if "--out" in args else ["--out", tmp_path / "sheet.png"]
    _fails(capsys, syneepose_cli.main, ["show", dataset, *out, *args], *words)
    assert not list(tmp_path.glob("sheet*"))


# --- python -m eval.run, tables, overlays --------------------------------------------------------------------

EVAL = [
    (["--k-r", 0], ["--k-r 0"]),
    (["--k-f", -2], ["--k-f -2"]),
    (["--n-templates", 0], ["--n-templates 0"]),
    (["--refit-growth", -1], ["refit growth -1"]),
    (["--scenes", "0,0"], ["--scenes names 0 twice"]),
    (["--scenes", ","], ["--scenes", "no scene"]),
    (["--scenes", "x"], ["--scenes 'x'"]),
    (["--scenes", 99], ["scene 99"]),
    (["--robots", "foo+bar"], ["foo"]),
    (["--mask-seed", -1], ["--mask-seed -1"]),
    (["--mask-noise", "foo"], ["--mask-noise 'foo'"]),
    (["--variant", "A", "--refine", "silhouette"], ["variant A"]),
    (["--silhouette", "robot"], ["silhouette 'robot'"]),
    (["--layer", 3], ["--layer"]),
    (["--bow-assignment", "nearest"], ["--bow-assignment 'nearest'"]),
    (["--hand-eye", "tsai"], ["does not take --hand-eye"]),
    (["--variant", "E"], ["--variant 'E' unknown; choose from A, B, C, D"]),
]


@pytest.mark.parametrize("args,words", EVAL, ids=[" ".join(map(str, a)) for a, _ in EVAL])
def test_eval_run_mistakes(capsys, tmp_path, dataset, args, words):
    out = tmp_path / "o"
    _fails(capsys, run.main, ["--method", "feepe", "--dataset", dataset, "--out", out, *args], *words)
    assert not out.exists()


def test_eval_run_dataset_and_method_mistakes(capsys, tmp_path, dataset):
    out = tmp_path / "o"
    for argv, words in (
            (["--method", "nosuch", "--dataset", dataset], ["nosuch"]),
            (["--method", "feepe", "--dataset", tmp_path / "none"], ["--dataset", "no such folder"]),
            (["--method", "bop-csv", "--dataset", dataset], ["needs --results"]),
            (["--method", "bop-csv", "--name", "x", "--dataset", dataset, "--results", tmp_path / "none.csv"],
             ["none.csv"])):
        _fails(capsys, run.main, [*argv, "--out", out], *words)
        assert not out.exists()


def test_bop_csv_rows_it_cannot_place(capsys, tmp_path, dataset):
    csv = gt_csv(tmp_path / "gt.csv", dataset)
    lines = csv.read_text().splitlines()
    fields = lines[1].split(",")
    for bad, word in ((",".join(["77", *fields[1:]]), "scene 77"),
                      (",".join([fields[0], "99", *fields[2:]]), "frame 99"),
                      ("header,wrong\n", "BOP header")):
        path = tmp_path / "bad.csv"
        path.write_text("\n".join([lines[0], bad]) + "\n" if "wrong" not in bad else bad)
        _fails(capsys, run.main, ["--method", "bop-csv", "--name", "x", "--dataset", dataset, "--results", path,
                                  "--out", tmp_path / "o"], word)
        assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("name,content,word", [
    ("dataset_info.json", "{trunc", "dataset_info.json: not valid JSON"),
    ("dataset_info.json", "[1]", "dataset_info.json"),
    ("test/000000/scene_gt.json", "{\"0\": [", "scene_gt.json: not valid JSON"),
    ("test/000000/scene_camera.json", "[]", "scene_camera.json"),
    ("test/000000/scene_camera.json", '{"0": {"depth_scale": 0.1}}', "frame 0 has no usable 'cam_K'"),
    ("test/000000/scene_gt.json", '{"0": [{"obj_id": 2, "cam_R_m2c": [1, 0]}]}', "frame 0 has no usable 'cam_R_m2c'"),
])
def test_eval_run_on_broken_data_set_files(capsys, tmp_path, dataset, name, content, word):
    broken = tmp_path / "data"
    shutil.copytree(dataset, broken)
    (broken / name).write_text(content)
    _fails(capsys, run.main, ["--method", "feepe", "--dataset", broken, "--out", tmp_path / "o"], word)


def test_tables_and_overlays_mistakes(capsys, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "summary.json").write_text("{x")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "summary.json").write_text('{"method": "x"}')
    good = tmp_path / "good"  # what the tables read, so the --out check is reached
    good.mkdir()
    (good / "summary.json").write_text(json.dumps({
        "method": "x", "dataset": {"path": str(tmp_path)}, "per_end_effector": {}, "ms_per_frame": 1.0,
        "average": {"add@1cm": 1.0, "adds@1cm": 1.0, "add@2cm": 1.0, "adds@2cm": 1.0}}))
    for main, argv, words in (
            (tables.main, [bad, "--out", tmp_path / "t"], ["summary.json: not valid JSON"]),
            (tables.main, [foreign, "--out", tmp_path / "t"], ["not an eval.run summary", "average"]),
            (tables.main, [tmp_path / "none", "--out", tmp_path / "t"], ["summary.json: missing"]),
            (tables.main, [good, "--out", afile], ["--out", "is a file"]),
            (overlays.main, [bad, "--out", tmp_path / "v"], ["summary.json: not valid JSON"]),
            (overlays.main, [foreign, "--out", tmp_path / "v"], ["dataset.path"]),
            (overlays.main, [tmp_path / "none", "--out", tmp_path / "v"], ["summary.json: missing"]),
            (overlays.main, [good, "--out", afile], ["models/"])):
        _fails(capsys, main, argv, *words)
    assert not (tmp_path / "t").exists() and not (tmp_path / "v").exists()


D435 = yaml.safe_load(Path("scenes/sensors/d435.yaml").read_text())
SENSORS = [("matcher.block", 4, "odd block size"), ("projector.power", "lots", "projector.power"),
           ("baseline", 0, "baseline = 0"), ("depth_range", [6, 0.2], "inverted"),
           ("matcher.blk", 5, "unknown key 'matcher.blk'"), ("ir_samples", 0, "ir_samples = 0"),
           ("imager.full_well", 0, "imager.full_well"), ("ir_render", "raytraced", "ir_render")]


@pytest.mark.parametrize("key,value,word", SENSORS, ids=[k for k, _, _ in SENSORS])
def test_sensor_profile_mistakes(capsys, tmp_path, key, value, word):
    content = json.loads(json.dumps(D435))
    *parents, last = key.split(".")
    node = content
    for p in parents:
        node = node[p]
    node[last] = value
    sensor = tmp_path / "s.yaml"
    sensor.write_text(yaml.safe_dump(content))
    out = tmp_path / "o"
    _fails(capsys, syneepose_cli.main, ["render", "--depth", "stereo", "--sensor", sensor, "--out", out],
           "s.yaml", word)
    assert not out.exists()
