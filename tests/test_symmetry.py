"""Claimed symmetries hold on the mesh (<= 1 % of the diameter); a non-symmetry is rejected; the
transforms models_info.json writes map the evaluation model onto itself, vertex by vertex."""

import json
from functools import cache

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from kernel.transforms import make_T, transform_points
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


# Vertex-by-vertex check of the transforms in models_eval/models_info.json (millimetres); the tolerances and
# their reasons are in the docstring of the test below.
SAMPLES_PER_MM2, COVER_MM, TOL_MM, SHARE, MAX_MM = 8.0, 0.7, 1.0, 0.97, 3.0
NOT_SYMMETRIES = {"90 deg": 90.0, "2 deg": 2.0}
PANDA_HAND_IS_NOT_SYMMETRIC = pytest.mark.xfail(
    strict=True, raises=AssertionError,
    reason="panda_hand's claimed 180 deg turn moves 10.9 % of its evaluation vertices more than 3 mm (up to 21 mm)")


@cache
def _eval_model(assets, obj_id: int) -> tuple[np.ndarray, cKDTree, dict]:
    """(vertices, KD-tree of the surface samples and vertices, models_info entry), mm."""
    mesh = trimesh.load(paths.models_eval_dir(assets) / f"obj_{obj_id:06d}.ply", process=False)
    samples, _ = trimesh.sample.sample_surface(mesh, int(SAMPLES_PER_MM2 * mesh.area), seed=0)
    tree = cKDTree(np.vstack([samples, mesh.vertices]))
    cover, _ = tree.query(trimesh.sample.sample_surface(mesh, 20000, seed=1)[0])
    assert cover.max() < COVER_MM, cover.max()  # fresh surface samples: how far a surface point lies from the tree
    info = json.loads((paths.models_eval_dir(assets) / "models_info.json").read_text())[str(obj_id)]
    return np.asarray(mesh.vertices), tree, info


def _info_transforms(info: dict) -> list[np.ndarray]:
    """Every transform models_info.json stands for (mm): the discrete ones, continuous ones at 10 deg steps."""
    out = [np.reshape(T, (4, 4)) for T in info.get("symmetries_discrete", [])]
    for sym in info.get("symmetries_continuous", []):
        offset = np.asarray(sym["offset"], dtype=float)
        for angle in np.deg2rad(np.arange(10, 360, 10)):
            R = Rotation.from_rotvec(np.asarray(sym["axis"], dtype=float) * angle).as_matrix()
            out.append(make_T(R, offset - R @ offset))
    return out


def _fit(vertices: np.ndarray, tree: cKDTree, T: np.ndarray) -> tuple[float, float]:
    """(share of T(vertices) within TOL_MM of the surface, largest distance, capped at 2 MAX_MM)."""
    d, _ = tree.query(transform_points(T, vertices), distance_upper_bound=2 * MAX_MM)
    return float(np.mean(d <= TOL_MM)), float(np.minimum(d, 2 * MAX_MM).max())


SYMMETRIC = sorted({n for n, _, _ in CLAIMED})


@pytest.mark.parametrize("name", [pytest.param(n, marks=PANDA_HAND_IS_NOT_SYMMETRIC) if n == "panda_hand" else n
                                  for n in SYMMETRIC])
def test_models_info_symmetries_map_the_evaluation_model_onto_itself(assets, catalog, name):
    """Every transform models_info.json gives carries at least SHARE (97 %) of the evaluation model's vertices
    to within TOL_MM (1 mm) of its surface, and every vertex to within MAX_MM (3 mm).

    Distances are to dense area-uniform surface samples plus the vertices (SAMPLES_PER_MM2 = 8 per mm2), so they
    exceed the distance to the surface by at most the samples' covering error (checked < COVER_MM = 0.7 mm;
    measured at most 0.56 mm over 20,000 fresh surface points): a vertex counted within 1 mm is within 1 mm.
    TOL_MM is BOP's remesh voxel: the two halves of an exactly symmetric model are remeshed on the same 1 mm
    grid, and a 0.5 deg turn keeps every vertex of the three grippers within it (measured: at most 0.89 mm).
    SHARE and MAX_MM: measured 97.9 % (2F-85) and 99.9 % (2F-140) within 1 mm under the claimed turn, every
    vertex within 2.6 / 2.8 mm; the rest lie on small features of the coupling plate (z < 0) that the turn does
    not carry onto themselves. Turns that are no symmetry fail SHARE (next test): 90 deg keeps 10-21 % of the
    vertices within 1 mm, 2 deg 73-83 %, 1 deg 87-94 %, on all three grippers.

    The Panda hand's 180 deg claim holds on average (0.55 % of the diameter, the build's rule, test above) but
    not vertex by vertex: 82.3 % within 1 mm, 10.9 % beyond 3 mm, up to 21.0 mm, at the two ends of the hand's
    body (x ~ y ~ +-70 mm, z -28..40 mm), which differ. It is marked as the expected failure it is, not hidden
    behind a looser bound: whether to keep the claim is the catalogue's decision."""
    vertices, tree, info = _eval_model(assets, catalog.end_effector(name).obj_id)
    transforms = _info_transforms(info)
    assert transforms, f"{name} claims symmetries in the catalogue, models_info.json has none"
    for T in transforms:
        share, worst = _fit(vertices, tree, T)
        assert share >= SHARE and worst <= MAX_MM, (share, worst)


@pytest.mark.parametrize("name", SYMMETRIC)
@pytest.mark.parametrize("turn", NOT_SYMMETRIES)
def test_a_turn_that_is_no_symmetry_fails_the_same_check(assets, catalog, name, turn):
    """The check above is tight enough to tell a symmetry from a turn that is none, by a wide margin."""
    vertices, tree, _ = _eval_model(assets, catalog.end_effector(name).obj_id)
    R = Rotation.from_euler("z", NOT_SYMMETRIES[turn], degrees=True).as_matrix()
    share, _ = _fit(vertices, tree, make_T(R))
    assert share < SHARE - 0.1, share
