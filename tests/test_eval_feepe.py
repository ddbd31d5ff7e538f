"""`python -m eval.run --method feepe` on real renders, then `python -m eval.tables` on its results."""

import json
import subprocess
import sys

import pytest


def _run(*args):
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True)


@pytest.fixture(scope="module")
def feepe_results(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("results")
    for variant in ("A", "D"):
        proc = _run("eval.run", "--method", "feepe", "--variant", variant, "--dataset", str(tiny_dataset),
                    "--out", str(out / variant))
        assert proc.returncode == 0, proc.stderr[-2000:]
    proc = _run("eval.run", "--method", "feepe", "--icp", "--dataset", str(tiny_dataset), "--out", str(out / "D+icp"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out


def test_run_writes_results_errors_and_summary(feepe_results, tiny_dataset):
    folder = feepe_results / "D"
    header = (folder / "results.csv").read_text().splitlines()[0]
    assert header == "scene_id,im_id,obj_id,score,R,t,time"
    assert len((folder / "errors.csv").read_text().splitlines()) == 1 + 12  # 2 scenes x 6 frames
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["options"]["variant"] == "D" and summary["backbone"] == "sift+normals+color"
    assert set(summary["per_end_effector"]) == {"robotiq_2f85", "kinova_3f"}
    icp = json.loads((feepe_results / "D+icp" / "summary.json").read_text())
    assert icp["options"]["icp"] is True and 0 <= icp["average"]["adds@1cm"] <= 100


def test_tables_and_curves_from_feepe_runs(feepe_results, tmp_path):
    out = tmp_path / "tables"
    proc = _run("eval.tables", *(str(feepe_results / v) for v in ("A", "D", "D+icp")), "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    ablation = (out / "ablation.md").read_text()
    assert "FEEPE A (sift+normals+color, mini)" in ablation and "FEEPE D + depth ICP (ours) (sift+normals+color, mini)" in ablation
    table1 = (out / "table1.md").read_text()
    assert "FEEPE D (sift+normals+color, mini)" in table1 and "FEEPE A (" not in table1  # ablations stay out
    assert (out / "accuracy_curves.png").stat().st_size > 10_000


def test_feepe_option_mistakes_are_one_line(tiny_dataset, tmp_path):
    proc = _run("eval.run", "--method", "feepe", "--layer", "19", "--dataset", str(tiny_dataset), "--out",
                str(tmp_path / "x"))
    assert proc.returncode == 2 and "DINOv2 options" in proc.stderr and "Traceback" not in proc.stderr
    proc = _run("eval.run", "--method", "feepe", "--n-templates", "960", "--dataset", str(tiny_dataset), "--out",
                str(tmp_path / "y"))
    assert proc.returncode == 2 and "no 960 templates for" in proc.stderr and "Traceback" not in proc.stderr
