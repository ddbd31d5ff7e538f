"""Reruns into an existing data set resume, refuse or re-render; they never mix two settings.

Tiny renders (64x48, 2 samples, 2 frames) through the real CLI.
"""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from kernel.bop import split_dir

ROBOT = "ur5e+robotiq_2f85"  # scene 7: 7th in the catalogue, one segment per configuration
OTHER = "panda+panda_hand"  # 0th
TINY = ["--preset", "mini", "--resolution", "64x48", "--samples", "2", "--segments", "1", "--frames", "2",
        "--robots", ROBOT]


def _render(out, *args):
    return subprocess.run([sys.executable, "-m", "syneepose", "render", "--out", str(out), *TINY, *args],
                          capture_output=True, text=True)


def _one_line(proc, *words):
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    [line] = proc.stderr.strip().splitlines()
    for word in words:
        assert word in line, line
    return line


def _files(root):
    return {p.relative_to(root): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def seed0(tmp_path_factory, assets):
    out = tmp_path_factory.mktemp("resume") / "seed0"
    proc = _render(out)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out


@pytest.fixture
def copy(seed0, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(seed0, out)
    return out


def _scene(out):
    [scene] = [p for p in split_dir(out).iterdir() if p.is_dir()]
    return scene


def test_every_scene_and_the_data_set_record_their_settings(seed0):
    info = json.loads((seed0 / "dataset_info.json").read_text())["settings"]
    scene = json.loads((_scene(seed0) / "scene_robot.json").read_text())["settings"]
    assert info == scene
    assert (scene["seed"], scene["frames"], scene["resolution"], scene["samples"]) == (0, 2, [64, 48], 2)
    assert len(scene["preset_sha256"]) == 16


@pytest.mark.parametrize("args,words", [
    (["--seed", "1"], ["seed 0 -> 1"]),
    (["--frames", "3"], ["frames 2 -> 3"]),
    (["--samples", "4"], ["samples 2 -> 4"]),
    (["--resolution", "80x60"], ["resolution [64, 48] -> [80, 60]"]),
    (["--marker"], ["marker False -> True"]),
    (["--hard", "occluder"], ["preset_sha256"]),
])
def test_a_rerun_with_other_settings_is_refused_and_writes_nothing(copy, args, words):
    before = _files(copy)
    _one_line(_render(copy, *args), "other settings", "--overwrite", *words)
    assert _files(copy) == before


def test_overwrite_renders_the_scene_again_as_a_fresh_run_would(copy, tmp_path):
    assert _render(copy, "--seed", "1", "--overwrite").returncode == 0
    fresh = tmp_path / "fresh"
    assert _render(fresh, "--seed", "1").returncode == 0
    for name in ("scene_camera.json", "scene_gt.json", "scene_robot.json"):
        assert (_scene(copy) / name).read_text() == (_scene(fresh) / name).read_text(), name
    assert json.loads((copy / "dataset_info.json").read_text())["settings"]["seed"] == 1
    assert not [p for p in copy.rglob("*") if "overwritten" in p.name]


def test_overwrite_never_leaves_other_scenes_of_other_settings_behind(copy):
    before = _files(copy)
    _one_line(_render(copy, "--samples", "4", "--overwrite", "--robots", "panda+panda_hand"),
              "--overwrite re-renders this run's scenes only", _scene(copy).name)
    assert _files(copy) == before


def test_a_resume_removes_what_a_killed_run_left(copy):
    scene = _scene(copy)
    leftovers = [scene / "tmpk1ll3d.exr", scene / "rgb" / ".000001.png.tmp999999", copy / ".models.tmp999999"]
    for path in leftovers[:2]:
        path.write_bytes(b"")
    leftovers[2].mkdir()
    assert _render(copy).returncode == 0
    assert not [p for p in leftovers if p.exists()]


def _from_before(out, *keys):
    """The data set as written before dataset_info.json and scene_robot.json held `keys`."""
    for path in (out / "dataset_info.json", _scene(out) / "scene_robot.json"):
        content = json.loads(path.read_text())
        for key in keys:
            content.pop(key, None)
        path.write_text(json.dumps(content))


def test_a_data_set_from_before_recorded_settings_is_judged_by_its_dataset_info(copy):
    _from_before(copy, "settings", "scenes")
    _one_line(_render(copy, "--seed", "3"), "seed 0 -> 3")
    assert _render(copy).returncode == 0  # the same settings resume, and are recorded from now on
    assert json.loads((copy / "dataset_info.json").read_text())["settings"]["seed"] == 0


def _scene_files(files):
    return {path: content for path, content in files.items() if path.parts[0] == "test"}


@pytest.fixture(scope="module")
def extended(seed0, tmp_path_factory):
    """seed0 with a configuration added, then a second segment per configuration: the files after each run."""
    out = tmp_path_factory.mktemp("extended") / "set"
    shutil.copytree(seed0, out)
    steps = [_files(out)]
    for args in (["--robots", f"{ROBOT},{OTHER}"], ["--robots", f"{ROBOT},{OTHER}", "--segments", "2"]):
        proc = _render(out, *args)
        assert proc.returncode == 0, proc.stderr[-2000:]
        steps.append(_files(out))
    return out, steps


def test_more_configurations_and_segments_add_scenes_and_keep_every_scene_as_it_was(extended):
    out, steps = extended
    for before, after in zip(steps, steps[1:]):
        kept = {path: after.get(path) for path in _scene_files(before)}
        assert kept == _scene_files(before)
        assert len(_scene_files(after)) > len(kept)
    scenes = json.loads((out / "dataset_info.json").read_text())["scenes"]
    assert scenes == {"0": {"config": OTHER, "segment": 0}, "7": {"config": ROBOT, "segment": 0},
                      "18": {"config": OTHER, "segment": 1}, "19": {"config": ROBOT, "segment": 1}}
    assert sorted(p.name for p in split_dir(out).iterdir()) == ["000000", "000007", "000018", "000019"]


def test_a_segment_shows_the_same_whichever_scene_id_it_got(extended, copy):
    """Segment 1 of ROBOT is scene 19 after OTHER came first, scene 18 when it is the only one added."""
    assert _render(copy, "--segments", "2").returncode == 0
    assert json.loads((copy / "dataset_info.json").read_text())["scenes"]["18"] == {"config": ROBOT, "segment": 1}
    out, _ = extended
    alone, after_other = _files(split_dir(copy) / "000018"), _files(split_dir(out) / "000019")
    assert alone == after_other and len(alone) > 10


def test_a_data_set_from_before_scene_ids_were_recorded_numbers_its_scenes_as_it_was_numbered(copy):
    _from_before(copy, "scenes")
    before = _scene_files(_files(copy))
    assert _render(copy, "--robots", f"{ROBOT},{OTHER}").returncode == 0
    scenes = json.loads((copy / "dataset_info.json").read_text())["scenes"]
    assert scenes == {"0": {"config": OTHER, "segment": 0}, "7": {"config": ROBOT, "segment": 0}}
    after = _files(copy)
    assert {path: after.get(path) for path in before} == before


@pytest.mark.parametrize("keys,scene,words", [
    (("scenes", "settings"), "000063", ["for segment counts 8, 9,", "another --out"]),
    (("scenes",), "000008", [f"scene 000008 holds {ROBOT}", "at 1 segments per configuration"]),
])
def test_a_data_set_from_before_whose_numbering_cannot_be_told_is_refused_and_left_alone(copy, keys, scene, words):
    _from_before(copy, *keys)
    _scene(copy).rename(split_dir(copy) / scene)
    before = _files(copy)
    _one_line(_render(copy), *words)
    assert _files(copy) == before


@pytest.mark.parametrize("name,content", [("dataset_info.json", "{trunc"), ("dataset_info.json", "[1, 2]"),
                                          ("scene_gt.json", "{\"0\": [")])
def test_a_broken_json_file_is_named_in_one_line(copy, name, content):
    path = copy / name if name == "dataset_info.json" else _scene(copy) / name
    path.write_text(content)
    _one_line(_render(copy), path.name)


def test_a_template_set_resumes_only_with_its_sample_count(tmp_path, assets):
    def templates(samples):
        return subprocess.run([sys.executable, "-m", "syneepose", "templates", "--out", str(tmp_path), "--ee",
                               "robotiq_2f85", "--views", "2", "--inplane", "1", "--resolution", "32", "--samples",
                               str(samples)], capture_output=True, text=True)

    assert templates(1).returncode == 0
    before = _files(tmp_path)
    _one_line(templates(2), "--samples 1, not 2")
    assert _files(tmp_path) == before


def test_the_template_settings_are_not_render_settings(copy, tmp_path):
    """Frames do not depend on the preset's `templates`: a preset differing only there resumes with nothing to
    do, and so do scenes recorded before issue 16, whose preset_sha256 counted the templates (mini's then
    20 x 12 views), while another render setting is still refused."""
    import yaml

    from syneepose.jobs import _digest
    from syneepose.preset import load_preset

    before = _files(copy)
    preset = yaml.safe_load(Path("scenes/mini.yaml").read_text())
    preset["templates"] = {"views": 7, "inplane": 3, "resolution": 64, "samples": 2}
    (tmp_path / "mini.yaml").write_text(yaml.safe_dump(preset))
    proc = _render(copy, "--preset", str(tmp_path / "mini.yaml"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    legacy = load_preset("mini").model_dump(mode="json", exclude={"hard"})  # recorded before `hard` existed
    legacy["templates"] = {"views": 20, "inplane": 12, "resolution": 128, "samples": 8}
    meta_path = _scene(copy) / "scene_robot.json"
    meta = json.loads(meta_path.read_text())
    meta["settings"]["preset_sha256"] = _digest(legacy)
    meta_path.write_text(json.dumps(meta))
    proc = _render(copy)
    assert proc.returncode == 0, proc.stderr[-2000:]
    after = _files(copy)
    assert {k for k in after if after[k] != before.get(k)} <= {_scene(copy).relative_to(copy) / "scene_robot.json",
                                                                 Path("dataset_info.json")}
    meta["settings"]["preset_sha256"] = "0" * 16
    meta_path.write_text(json.dumps(meta))
    _one_line(_render(copy), "preset_sha256 0000000000000000 ->")


def test_the_denoisers_prefilter_is_a_render_setting(copy, tmp_path):
    """mini renders with the fast prefilter (issue 36); the same preset with Cycles' default one renders other
    pixels, so a resume with it is refused, while a preset that never names the prefilter keeps the digest
    it had before the key existed (scenes rendered then still resume)."""
    import yaml

    from syneepose.jobs import _digest
    from syneepose.preset import parse_preset

    preset = yaml.safe_load(Path("scenes/mini.yaml").read_text())
    assert preset["render"]["denoise_prefilter"] == "fast"
    preset["render"]["denoise_prefilter"] = "accurate"
    (tmp_path / "mini.yaml").write_text(yaml.safe_dump(preset))
    _one_line(_render(copy, "--preset", str(tmp_path / "mini.yaml")), "other settings", "preset_sha256")

    other = tmp_path / "accurate"
    assert _render(other, "--preset", str(tmp_path / "mini.yaml")).returncode == 0
    rgb = sorted(p.relative_to(copy) for p in copy.rglob("rgb/*.png"))
    assert rgb and any((copy / p).read_bytes() != (other / p).read_bytes() for p in rgb)

    unnamed = {**preset, "render": {k: v for k, v in preset["render"].items() if k != "denoise_prefilter"}}
    assert (_digest(parse_preset(unnamed).digest_content()) == _digest(parse_preset(preset).digest_content())
            != _digest(parse_preset({**preset, "render": {**preset["render"], "denoise_prefilter": "fast"}})
                       .digest_content()))
