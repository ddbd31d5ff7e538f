"""The built assets: 18 loadable URDFs, catalogue facts that must agree with the converted models."""

import json
import shutil

import numpy as np
import pytest
import trimesh
import yourdfpy

from syneepose import paths
from syneepose.robots.build import build_assets
from syneepose.robots.catalog import load_catalog
from syneepose.robots.kinematics import Kinematics
from syneepose.robots.model import read_urdf
from syneepose.robots.robot import load_robot

CONFIGS = load_catalog().configurations


def test_eighteen_configurations(catalog):
    assert len(CONFIGS) == 18
    assert set(catalog.arms) == {"panda", "ur5e", "ur10e"}
    assert set(catalog.end_effectors) == {"panda_hand", "robotiq_2f85", "robotiq_2f140", "kinova_3f",
                                          "robotiq_3f", "shadow_hand"}


@pytest.mark.parametrize("config", CONFIGS)
def test_config_loads_with_yourdfpy_and_every_mesh_resolves(assets, config):
    urdf = yourdfpy.URDF.load(str(paths.config_urdf(config, assets)), build_scene_graph=True, load_meshes=True)
    n_visuals = sum(len(link.visuals) for link in urdf.robot.links)
    assert n_visuals > 10
    assert len(urdf.scene.graph.nodes_geometry) == n_visuals
    assert all(len(g.faces) > 0 for g in urdf.scene.geometry.values())
    assert urdf.validate()


def test_second_build_does_no_work(assets):
    report = build_assets(assets, log=lambda *_: None)
    assert not report.did_work
    assert report.seconds < 5.0


@pytest.mark.parametrize("name", list(load_catalog().arms))
def test_arm_catalogue_matches_urdf(assets, catalog, name):
    arm = catalog.arm(name)
    model = read_urdf(paths.part_urdf(name, assets))
    for joint, (lo, hi), home in zip(arm.joints, arm.limits, arm.home):
        j = model.joint(joint)
        assert j.type in ("revolute", "continuous")
        if j.type == "revolute":
            assert j.lower - 1e-6 <= lo < hi <= j.upper + 1e-6, joint
        assert lo <= home <= hi, joint


@pytest.mark.parametrize("name", list(load_catalog().end_effectors))
def test_ee_canonical_within_limits_and_tcp(assets, catalog, name):
    ee = catalog.end_effector(name)
    model = read_urdf(paths.part_urdf(name, assets))
    kin = Kinematics(model)
    values = kin.joint_values(dict(ee.canonical))
    for joint, value in values.items():
        j = model.joint(joint)
        if j.type in ("revolute", "prismatic"):
            assert j.lower - 1e-9 <= float(value) <= j.upper + 1e-9, (joint, float(value))
    if "eef" in {lk.name for lk in model.links}:  # robosuite grippers mark their TCP with an `eef` body
        tcp = kin.pose("eef", dict(ee.canonical))[:3, 3]
        np.testing.assert_allclose(tcp, ee.tcp, atol=1e-4)


@pytest.mark.parametrize("config", ["panda+robotiq_2f85", "ur5e+shadow_hand", "ur10e+panda_hand"])
def test_T_base_ee_is_flange_pose_and_batches(assets, config):
    robot = load_robot(config, assets)
    rng = np.random.default_rng(0)
    lo, hi = np.array(robot.arm.limits).T
    q = rng.uniform(lo, hi, size=(5, len(lo)))
    T = robot.T_base_ee(q)
    assert T.shape == (5, 4, 4)
    arm_kin = Kinematics(read_urdf(paths.part_urdf(robot.arm.name, assets)))
    for i in range(5):
        poses = arm_kin.link_poses(dict(zip(robot.arm.joints, q[i])))
        T_ref = np.linalg.inv(poses[robot.arm.base_link]) @ poses[robot.arm.flange_link]
        np.testing.assert_allclose(T[i], T_ref, atol=1e-12)
        np.testing.assert_allclose(robot.T_base_ee(q[i]), T[i], atol=1e-12)


def test_bop_models(assets, catalog):
    infos = json.loads((paths.models_dir(assets) / "models_info.json").read_text())
    assert set(infos) == {str(e.obj_id) for e in catalog.end_effectors.values()}
    for ee in catalog.end_effectors.values():
        info = infos[str(ee.obj_id)]
        mesh = trimesh.load(paths.models_dir(assets) / f"obj_{ee.obj_id:06d}.ply", process=False)
        lo, hi = mesh.bounds
        np.testing.assert_allclose([info["min_x"], info["min_y"], info["min_z"]], lo, atol=1e-3)
        np.testing.assert_allclose([info["size_x"], info["size_y"], info["size_z"]], hi - lo, atol=1e-3)
        assert 100.0 < info["diameter"] < 600.0  # millimetres: grippers 0.1-0.3 m, the Shadow hand 0.45 m
        assert info["diameter"] >= np.linalg.norm(hi - lo) * 0.5
        assert mesh.visual.vertex_colors.shape == (len(mesh.vertices), 4)
        assert ("symmetries_discrete" in info) == any(order > 0 for _, order in ee.symmetries)


def test_subset_build_keeps_every_model(tmp_path, assets, catalog):
    out = tmp_path / "assets"
    # models_eval/ takes a minute of voxel remeshing; a copy whose stamp matches the recipe must be kept as is
    shutil.copytree(paths.models_eval_dir(assets), paths.models_eval_dir(out))
    report = build_assets(out, ["ur5e+robotiq_2f85"], log=lambda *_: None)
    assert report.models and not report.models_eval
    infos = json.loads((paths.models_dir(out) / "models_info.json").read_text())
    assert len(infos) == len(catalog.end_effectors)
    assert paths.config_urdf("ur5e+robotiq_2f85", out).is_file()
    assert not paths.config_urdf("panda+robotiq_2f85", out).exists()
