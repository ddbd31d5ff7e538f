"""User mistakes give one clear error line, never a traceback, and leave nothing half-built."""

import shutil
import subprocess
import sys

import pytest

from kernel.errors import UserError
from syneepose import paths
from syneepose.robots import build as build_mod
from syneepose.robots.catalog import Source, load_catalog
from syneepose.robots.model import read_urdf
from syneepose.robots.robot import load_robot
from syneepose.robots.sources import ensure_source


def _cli(*args, **kw):
    return subprocess.run([sys.executable, "-m", "syneepose", *args], capture_output=True, text=True, **kw)


@pytest.mark.parametrize("robots,word", [("ur5e+gripper9", "gripper9"), ("kuka+robotiq_2f85", "kuka"),
                                         ("ur5e", "ARM+EE")])
def test_unknown_names_one_line_error(robots, word):
    proc = _cli("assets", "--robots", robots)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and word in lines[0]


def test_load_robot_unknown_name():
    with pytest.raises(UserError, match="known end-effectors"):
        load_robot("ur5e+nohand")


def test_missing_source_package(tmp_path, monkeypatch):
    monkeypatch.setenv("SYNEEPOSE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("PIP_NO_INDEX", "1")
    monkeypatch.setenv("PIP_FIND_LINKS", str(tmp_path))
    source = Source("nothing", "syneepose-no-such-package==0.0.1", "MIT", (), ("x/",))
    with pytest.raises(UserError, match="could not obtain syneepose-no-such-package==0.0.1"):
        ensure_source(source)
    assert not (tmp_path / "cache" / "sources").exists() or not any((tmp_path / "cache" / "sources").iterdir())


def test_urdf_with_missing_mesh(assets, tmp_path):
    part = tmp_path / "robotiq_2f85"
    shutil.copytree(paths.part_dir("robotiq_2f85", assets), part)
    victim = sorted((part / "meshes").iterdir())[0]
    victim.unlink()
    with pytest.raises(UserError, match=victim.name):
        read_urdf(part / "robotiq_2f85.urdf")


def test_unwritable_output(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    proc = _cli("assets", "--robots", "ur5e+robotiq_2f85", "--out", str(blocker / "assets"))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "cannot write the assets folder" in proc.stderr


def _leftovers(root):
    return [p for p in root.rglob("*") if ".tmp" in p.name or ".old" in p.name]


def test_failed_part_build_leaves_nothing(tmp_path, monkeypatch, assets):
    out = tmp_path / "assets"

    def broken(*_a, **_k):
        raise UserError("simulated failure while writing meshes")

    monkeypatch.setattr(build_mod, "write_urdf", broken)
    with pytest.raises(UserError, match="simulated"):
        build_mod.build_assets(out, ["ur5e+robotiq_2f85"], log=lambda *_: None)
    assert not paths.part_dir("ur5e", out).exists()
    assert not _leftovers(out)


def test_failed_models_build_keeps_previous_models(tmp_path, monkeypatch, assets):
    out = tmp_path / "assets"
    build_mod.build_assets(out, ["ur5e+robotiq_2f85"], log=lambda *_: None)
    before = (paths.models_dir(out) / "models_info.json").read_text()

    def broken(*_a, **_k):
        raise UserError("simulated failure in the models step")

    monkeypatch.setattr(build_mod.ee_models, "model_info", broken)
    with pytest.raises(UserError, match="simulated"):
        build_mod.build_assets(out, ["ur5e+robotiq_2f85"], force=True, log=lambda *_: None)
    assert (paths.models_dir(out) / "models_info.json").read_text() == before
    assert not _leftovers(out)


def test_catalogue_symmetry_claim_that_does_not_hold_is_refused(assets, catalog):
    from dataclasses import replace

    from syneepose.robots.ee_models import load_ee_mesh, model_info

    ee = replace(catalog.end_effector("robotiq_3f"), symmetries=(("z", 3),))
    mesh = load_ee_mesh(ee, paths.part_urdf("robotiq_3f", assets))
    with pytest.raises(UserError, match="does not hold"):
        model_info(mesh, ee)


def test_load_catalog_rejects_bad_symmetry():
    from syneepose.robots.catalog import _symmetry

    with pytest.raises(UserError):
        _symmetry("x", {"axis": "w", "order": 2})
    assert load_catalog() is load_catalog()


@pytest.mark.parametrize("options,word", [({"k_f": -2}, "k_f"), ({"memory_threshold_deg": -1}, "memory_threshold_deg"),
                                          ({"silhouette_starts": 0}, "silhouette_starts"),
                                          ({"silhouette_sigmas_px": ()}, "silhouette_sigmas_px"),
                                          ({"icp_sigma_m": 0.0}, "icp_sigma_m"),
                                          ({"silhouette_key_frames": -1}, "silhouette_key_frames"),
                                          ({"silhouette_memory_m": 0.0}, "silhouette_memory_m")])
def test_estimator_options_out_of_range_are_named(options, word):
    from feepe.estimator import FeepeOptions

    with pytest.raises(UserError, match=word):
        FeepeOptions(**options)


@pytest.mark.parametrize("options,word", [({"k_r": 0}, "k_r"), ({"pad": 0.0}, "pad"), ({"max_matches": 2}, "max_matches")])
def test_single_frame_options_out_of_range_are_named(options, word):
    from feepe.candidates import SingleFrameOptions

    with pytest.raises(UserError, match=word):
        SingleFrameOptions(**options)
