"""Shared fixtures: the built robot assets (built once per session by `make assets` or here)."""

from pathlib import Path

import pytest

from syneepose import paths


@pytest.fixture(scope="session")
def assets() -> Path:
    from syneepose.robots.build import build_assets

    build_assets(log=lambda *_: None)
    return paths.assets_dir()


@pytest.fixture(scope="session")
def catalog():
    from syneepose.robots.catalog import load_catalog

    return load_catalog()


TINY_CONFIGS = ("ur5e+robotiq_2f85", "panda+kinova_3f")
TINY_TEMPLATES = ("12", "4", "96")  # views, in-plane rotations, pixels


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory, assets) -> Path:
    """A small rendered data set with templates, through the real CLI: 2 segments of 6 frames at 160x120
    and 48 templates per end-effector. Used by the FEEPE, evaluator and report tests.

    The templates are rendered one by one (`--inplane-by rendered`), as when the FEEPE bounds of
    test_eval_feepe were measured: on these 12 frames FEEPE D's ADD AUC moves by 10-30 points with
    noise-level changes of the templates (rendered at 4 / 8 / 16 spp: 42.4 / 32.3 / 34.7; rolled in-plane
    rotations at the same counts: 14.9 / 30.1 / 14.3, masks equal to IoU 0.999), so the tests keep the set
    they were measured on. Rolled templates are tested in test_templates_inplane, and what they change for
    FEEPE is measured on mini's 288 frames (docs/feepe.md, "Templates rolled or rendered")."""
    import subprocess
    import sys

    out = tmp_path_factory.mktemp("tiny")
    render = [sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--out", str(out), "--robots",
              ",".join(TINY_CONFIGS), "--segments", "1", "--frames", "6", "--resolution", "160x120", "--samples", "4"]
    views, inplane, res = TINY_TEMPLATES
    templates = [sys.executable, "-m", "syneepose", "templates", "--out", str(out), "--ee",
                 ",".join(c.split("+")[1] for c in TINY_CONFIGS), "--views", views, "--inplane", inplane,
                 "--resolution", res, "--samples", "4", "--inplane-by", "rendered"]
    for cmd in (render, templates):
        proc = subprocess.run(cmd, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr[-2000:]
    return out
