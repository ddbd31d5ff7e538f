"""Overlays and the HTML report of a real `python -m eval.run --method feepe` result on the tiny rendered set;
the report is opened in headless Chromium, which must load every image without a console message."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import pytest

from kernel.drawing import LINE_H


def _run(*args):
    return subprocess.run([sys.executable, "-m", *map(str, args)], capture_output=True, text=True)


@pytest.fixture(scope="module")
def feepe_run(tiny_dataset, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("results") / "feepe-D"
    proc = _run("eval.run", "--method", "feepe", "--dataset", tiny_dataset, "--out", out)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out


def _chromium() -> str:
    path = shutil.which("chromium") or "/usr/bin/chromium"
    if not Path(path).is_file():
        pytest.fail("chromium is missing: `make test` installs it (apt-get install chromium)")
    return path


def open_in_chromium(index: Path, tmp_path: Path) -> tuple[str, list[str]]:
    """The DOM after the page's load event and the console messages Chromium logged."""
    proc = subprocess.run(
        [_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         f"--user-data-dir={tmp_path / 'chromium-profile'}", "--enable-logging=stderr", "--v=0", "--dump-dom",
         index.resolve().as_uri()], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout, [line for line in proc.stderr.splitlines() if ":CONSOLE" in line]


def test_overlays_of_a_segment_and_its_gif(feepe_run, tmp_path):
    proc = _run("eval.overlays", feepe_run, "--out", tmp_path, "--scenes", "7", "--gif")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert sorted(p.name for p in (tmp_path / "000007").iterdir()) == [f"{i:06d}.png" for i in range(6)]
    gif = iio.imread(tmp_path / "000007.gif")
    assert gif.shape[:3] == (6, 120 + LINE_H, 160 + 2 + 120)  # every frame, its zoom beside it, captioned

    proc = _run("eval.overlays", feepe_run, "--out", tmp_path, "--scenes", "99")
    assert proc.returncode == 2 and "no scene 99" in proc.stderr and "Traceback" not in proc.stderr


def test_report_loads_in_headless_chromium_with_every_image(feepe_run, tmp_path):
    out = tmp_path / "report"
    proc = _run("eval.report", feepe_run, "--out", out, "--gif")
    assert proc.returncode == 0, proc.stderr[-2000:]
    page = (out / "index.html").read_text()
    sources = re.findall(r'<img src="([^"]+)"', page)
    # the curves and the convergence plot, then per end-effector (2) the 3 worst frames and the GIF of the
    # worst frame's segment
    assert len(sources) == 2 + 2 * (3 + 1) and sources[:2] == ["tables/accuracy_curves.png", "tables/convergence.png"]
    assert all(not Path(s).is_absolute() and (out / s).is_file() for s in sources)

    dom, console = open_in_chromium(out / "index.html", tmp_path)
    assert console == []
    assert f">{len(sources)} of {len(sources)} images loaded<" in dom
    assert "Table I: AUC@1cm of ADD/ADD-S per end-effector" in dom and dom.count("<table>") == 6  # runs + 5 tables
    assert "FEEPE D (sift+normals+color, mini)" in dom and "robotiq_2f85" in dom

    (out / sources[-1]).unlink()  # the page says when an image is missing
    dom, _ = open_in_chromium(out / "index.html", tmp_path)
    assert f">{len(sources) - 1} of {len(sources)} images loaded; missing: {sources[-1]}" in dom


def test_report_replaces_a_report_and_refuses_other_folders(feepe_run, tmp_path):
    out = tmp_path / "report"
    assert _run("eval.report", feepe_run, "--out", out, "--worst", "1").returncode == 0
    (out / "img" / "stale.png").write_bytes(b"")
    assert _run("eval.report", feepe_run, "--out", out, "--worst", "1").returncode == 0
    assert not (out / "img" / "stale.png").exists() and len(list((out / "img").rglob("*.png"))) == 2
    assert [p.name for p in tmp_path.iterdir()] == ["report"]  # no staging folder left behind

    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "todo.txt").write_text("mine")
    proc = _run("eval.report", feepe_run, "--out", tmp_path / "notes")
    assert proc.returncode == 2 and "not a report" in proc.stderr and "Traceback" not in proc.stderr
    assert (tmp_path / "notes" / "todo.txt").read_text() == "mine"


def test_own_masks_are_shown_in_the_run_table_and_the_captions(tmp_path):
    from eval import report
    from eval.tables import Run
    from tests.test_eval_summary import _frame

    summary = {"method": "feepe", "dataset": {"path": "data/mini"}, "n_frames": 2, "n_failures": 0,
               "average": {"add@1cm": 90.0, "adds@1cm": 95.0}, "ms_per_frame": 80.0,
               "own_masks": {"n_frames": 2, "ee_iou": {"median": 0.9512, "mean": 0.95},
                             "robot_iou": {"median": 0.9871, "mean": 0.98}}}
    table = report._metadata([Run(tmp_path, summary, "FEEPE")])
    assert "<td>0.951 / 0.987</td>" in table and "Own masks" in table
    given = report._metadata([Run(tmp_path, {**summary, "own_masks": None}, "FEEPE")])
    assert "<td>– / –</td>" not in given and "<td>–</td>" in given
    row = _frame("a", 0, 0.001)
    row.ee_mask_iou, row.robot_mask_iou = 0.9, 0.95
    assert report._caption(row).endswith("own masks' IoU 0.90 (end-effector) 0.95 (robot)")
    assert "IoU" not in report._caption(_frame("a", 0, 0.001))
