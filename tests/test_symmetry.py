"""Claimed symmetries hold on the mesh (<= 1 % of the diameter); a non-symmetry is rejected."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kernel.transforms import make_T
from syneepose import paths
from syneepose.robots.catalog import load_catalog
from syneepose.robots.ee_models import load_ee_mesh
from syneepose.robots.symmetry import check_symmetry, diameter, symmetry_error

EES = list(load_catalog().end_effectors)
CLAIMED = [(n, a, o) for n in EES for a, o in load_catalog().end_effector(n).symmetries]


def test_claims_cover_the_two_finger_grippers():
    assert {n for n, _, _ in CLAIMED} == {"panda_hand", "robotiq_2f85", "robotiq_2f140"}


@pytest.mark.parametrize("name,axis,order", CLAIMED)
def test_claimed_symmetry_holds(assets, catalog, name, axis, order):
    mesh = load_ee_mesh(catalog.end_effector(name), paths.part_urdf(name, assets))
    holds, err = check_symmetry(mesh, axis, order)
    assert holds and err <= 0.01
    info = json.loads((paths.models_dir(assets) / "models_info.json").read_text())
    sym = np.array(info[str(catalog.end_effector(name).obj_id)]["symmetries_discrete"]).reshape(-1, 4, 4)
    assert len(sym) == order - 1
    np.testing.assert_allclose(sym[0][:3, :3] @ sym[0][:3, :3].T, np.eye(3), atol=1e-9)


@pytest.mark.parametrize("name", EES)
def test_random_rotation_is_not_a_symmetry(assets, catalog, name):
    mesh = load_ee_mesh(catalog.end_effector(name), paths.part_urdf(name, assets))
    rng = np.random.default_rng(3)
    T = make_T(Rotation.from_rotvec(rng.normal(size=3) / np.sqrt(3) * np.deg2rad(40)).as_matrix())
    assert symmetry_error(mesh, T, n_samples=500) / diameter(mesh) > 0.01


@pytest.mark.parametrize("name", ["kinova_3f", "robotiq_3f"])
def test_three_finger_grippers_have_no_threefold_symmetry(assets, catalog, name):
    """Measured: the 3-finger hands miss 3-fold symmetry by 2 % of their diameter (docs/syneepose.md, symmetries)."""
    mesh = load_ee_mesh(catalog.end_effector(name), paths.part_urdf(name, assets))
    holds, err = check_symmetry(mesh, "z", 3, n_samples=500)
    assert not holds and err > 0.01
