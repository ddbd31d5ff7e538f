"""`python -m syneepose show` on the tiny rendered set: one tile per configuration, the ground-truth outline
drawn in every tile, one template sheet per end-effector of the known grid size, one-line user errors."""

import subprocess
import sys

import cv2
import numpy as np

from kernel.drawing import GT_COLOUR, LINE_H
from syneepose.show import PAD, contact_sheet
from tests.conftest import TINY_CONFIGS, TINY_TEMPLATES


def _show(*args):
    return subprocess.run([sys.executable, "-m", "syneepose", "show", *map(str, args)], capture_output=True, text=True)


def test_contact_sheet_has_one_tile_per_configuration(tiny_dataset, tmp_path):
    out = tmp_path / "sheet.png"
    proc = _show(tiny_dataset, "--out", out, "--frames", 3)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "2 configurations" in proc.stdout

    sheet = contact_sheet(tiny_dataset, frames=3)
    assert [t.config for t in sheet.tiles] == sorted(TINY_CONFIGS)
    assert np.array_equal(cv2.imread(str(out))[..., ::-1], sheet.image)  # the CLI wrote this very sheet
    for tile in sheet.tiles:
        x, y, w, h = tile.box
        assert len(tile.scene_ids) == 1
        assert (w, h) == (3 * 160 + 2 * 2, LINE_H + 120 + 120 + LINE_H)  # title; 3 frames: RGB, depth, caption
        rgb_rows = sheet.image[y + LINE_H:y + LINE_H + 120, x:x + w]
        assert (rgb_rows == GT_COLOUR).all(axis=-1).sum() > 20  # the mask outline is drawn
    x0, y0, w0, _ = sheet.tiles[0].box
    assert sheet.tiles[1].box[:2] == (x0 + w0 + PAD, y0)  # side by side: 2 tiles, one row


def test_template_sheet_per_end_effector(tiny_dataset, tmp_path):
    out = tmp_path / "sheet.png"
    assert _show(tiny_dataset, "--out", out).returncode == 0
    views, inplane, res = (int(v) for v in TINY_TEMPLATES)
    for config in TINY_CONFIGS:
        ee = config.split("+")[1]
        image = cv2.imread(str(tmp_path / f"sheet-templates-{ee}_{views}x{inplane}_{res}px.png"))
        columns, rows = 5, -(-views // 5)  # in-plane rotation 0 of every view
        assert image.shape == (LINE_H + rows * (res + LINE_H + PAD) + PAD, columns * (res + PAD) + PAD, 3)


def test_show_mistakes_are_one_line(tiny_dataset, tmp_path):
    for args, message in (([tmp_path / "nothing"], "no train/ folder"),
                          ([tiny_dataset, "--out", tmp_path / "sheet.jpg"], "give a .png file name"),
                          ([tiny_dataset, "--out", tmp_path / "s.png", "--frames", 0], "--frames 0: must lie in 1..16"),
                          ([tiny_dataset, "--out", tmp_path / "s.png", "--width", 100000], "--width 100000")):
        proc = _show(*args)
        assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
        assert proc.stderr.count("\n") == 1
