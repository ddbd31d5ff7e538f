"""FK on small hand-made robots with known answers."""

import numpy as np
import pytest

from kernel.errors import UserError
from kernel.transforms import make_T
from syneepose.robots.kinematics import Kinematics
from syneepose.robots.model import Joint, Link, Mimic, RobotModel, read_urdf, write_urdf


def _two_link(mimic=None):
    links = [Link("base"), Link("a"), Link("b"), Link("c")]
    joints = [
        Joint("j1", "revolute", "base", "a", make_T(t=[0, 0, 1.0]), np.array([0, 0, 1.0]), -3, 3),
        Joint("j2", "prismatic", "a", "b", make_T(t=[1.0, 0, 0]), np.array([1.0, 0, 0]), 0, 1),
        Joint("j3", "revolute", "a", "c", make_T(t=[0, 1.0, 0]), np.array([0, 0, 1.0]), -3, 3, mimic),
    ]
    return RobotModel("toy", links, joints)


def test_known_answer():
    kin = Kinematics(_two_link())
    poses = kin.link_poses({"j1": np.pi / 2, "j2": 0.5})
    np.testing.assert_allclose(poses["a"][:3, 3], [0, 0, 1])
    np.testing.assert_allclose(poses["b"][:3, 3], [0, 1.5, 1], atol=1e-12)  # x rotated onto y
    np.testing.assert_allclose(poses["b"][:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)


def test_mimic_follows_master_unless_given():
    kin = Kinematics(_two_link(Mimic("j1", -2.0, 0.1)))
    assert kin.actuated == ["j1", "j2"]
    values = kin.joint_values({"j1": 0.3})
    assert values["j3"] == pytest.approx(-0.5)
    assert kin.joint_values({"j1": 0.3, "j3": 1.0})["j3"] == 1.0


def test_batched_equals_single():
    kin = Kinematics(_two_link(Mimic("j1")))
    q1 = np.linspace(-1, 1, 7)
    q2 = np.linspace(0, 1, 7)
    batch = kin.link_poses({"j1": q1, "j2": q2})
    for i in range(7):
        single = kin.link_poses({"j1": q1[i], "j2": q2[i]})
        for name in single:
            np.testing.assert_allclose(batch[name][i], single[name], atol=1e-14)


def test_urdf_round_trip(tmp_path):
    model = _two_link(Mimic("j1", 0.5, 0.25))
    write_urdf(model, tmp_path / "toy.urdf")
    back = read_urdf(tmp_path / "toy.urdf")
    q = {"j1": 0.7, "j2": 0.2}
    a, b = Kinematics(model).link_poses(q), Kinematics(back).link_poses(q)
    for name in a:
        np.testing.assert_allclose(a[name], b[name], atol=1e-15)
    assert back.joint("j3").mimic == Mimic("j1", 0.5, 0.25)


def test_unknown_joint_is_a_user_error():
    with pytest.raises(UserError, match="no joints"):
        Kinematics(_two_link()).link_poses({"elbow": 1.0})
