"""FK of every converted part against MuJoCo on the original source file."""

import numpy as np
import pytest

from kernel.transforms import inv_T, rotation_angle
from syneepose import paths
from syneepose.robots.catalog import EndEffector, load_catalog
from syneepose.robots.kinematics import Kinematics
from syneepose.robots.model import read_urdf
from syneepose.robots.sources import ensure_source
from tests.mujoco_reference import link_frames, random_qpos, reference_model

PARTS = list(load_catalog().arms) + list(load_catalog().end_effectors)


@pytest.mark.parametrize("name", PARTS)
def test_part_fk_matches_mujoco(assets, catalog, name):
    part = catalog.part(name)
    m = reference_model(part, ensure_source(catalog.sources[part.source]))
    kin = Kinematics(read_urdf(paths.part_urdf(name, assets)))
    T_root_world = part.T_mount_source if isinstance(part, EndEffector) else np.eye(4)
    rng = np.random.default_rng(7)
    compared = 0
    for _ in range(20):
        q = random_qpos(m, rng)
        # Every joint given, so mimic tables are bypassed; source joints we dropped (the hand the
        # Panda arm file carries) are left out.
        ours = kin.link_poses({k: v for k, v in q.items() if k in kin.joint_names})
        ref = link_frames(m, q)
        for body, T_ref in ref.items():
            if body not in ours:
                continue
            T = inv_T(T_root_world) @ ours[body]
            assert np.abs(T[:3, 3] - T_ref[:3, 3]).max() <= 1e-6, (name, body)
            assert rotation_angle(T[:3, :3], T_ref[:3, :3]) <= 1e-6, (name, body)
            compared += 1
    n_links = sum(1 for b in ref if b in ours)
    assert n_links >= len(kin.joint_names), (name, n_links)
    assert compared == 20 * n_links
