"""`python -m syneepose dataset` (make dataset): the render and the templates under one progress bar, the
same files as the two commands run one after the other."""

import filecmp
import subprocess
import sys
from pathlib import Path

import yaml

ROBOTS = "ur5e+robotiq_2f85,panda+kinova_3f"


def _tiny_preset(tmp_path):
    preset = yaml.safe_load(Path("scenes/mini.yaml").read_text())
    preset.update(name="tiny", frames=2, resolution=[48, 36], samples=1,
                  templates={"views": 2, "inplane": 2, "resolution": 32, "samples": 1})
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(preset))
    return str(path)


def _run(*args):
    return subprocess.run([sys.executable, "-m", "syneepose", *args], capture_output=True, text=True)


def _same_tree(a, b) -> bool:
    diff = filecmp.dircmp(a, b)
    stack = [diff]
    while stack:
        d = stack.pop()
        if d.left_only or d.right_only or d.diff_files or d.funny_files:
            return False
        _, mismatch, errors = filecmp.cmpfiles(d.left, d.right, d.common_files, shallow=False)
        if mismatch or errors:
            return False
        stack.extend(d.subdirs.values())
    return True


def test_dataset_is_render_then_templates_under_one_bar(tmp_path, assets):
    preset = _tiny_preset(tmp_path)
    proc = _run("dataset", "--preset", preset, "--robots", ROBOTS, "--out", str(tmp_path / "one"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    bars = {line.split(":")[0] for line in proc.stderr.replace("\r", "\n").splitlines() if "%|" in line}
    assert bars == {"dataset"}
    assert "render 4/4, templates 8/8" in proc.stderr
    assert proc.stdout.splitlines()[-2:] == [f"render: 2 segments in {tmp_path / 'one' / 'test'}",
                                             f"templates: 2 end-effectors in {tmp_path / 'one' / 'templates'}"]
    for command in (["render", "--robots", ROBOTS], ["templates", "--ee", "robotiq_2f85,kinova_3f"]):
        assert _run(*command, "--preset", preset, "--out", str(tmp_path / "two")).returncode == 0
    assert _same_tree(tmp_path / "one", tmp_path / "two")


def test_dataset_refuses_bad_input_before_rendering(tmp_path, assets):
    proc = _run("dataset", "--robots", "ur5e+nothing", "--out", str(tmp_path / "x"))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "unknown end-effector 'nothing'" in proc.stderr
    assert not (tmp_path / "x").exists()
