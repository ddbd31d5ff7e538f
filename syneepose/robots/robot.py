"""An assembled configuration `ARM+EE`: arm + fixed flange-to-mount joint + end-effector.

`T_base_link(q)` and `T_base_ee(q)` take the arm joint values (shape (..., n_arm)); the fingers hold
the end-effector's canonical configuration, as in every rendered frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kernel.errors import UserError
from kernel.transforms import inv_T
from syneepose import paths
from syneepose.robots.catalog import Arm, EndEffector, load_catalog
from syneepose.robots.kinematics import Kinematics
from syneepose.robots.model import Joint, RobotModel, read_urdf
from syneepose.robots.parts import EE_ROOT

MOUNT_JOINT = "flange_to_ee_mount"


def assemble(config: str, arm: RobotModel, ee: RobotModel, flange_link: str) -> RobotModel:
    """Meshes are re-rooted to `parts/<name>/` so the URDF sits beside the parts folder."""
    clash = {lk.name for lk in arm.links} & {lk.name for lk in ee.links}
    clash |= {j.name for j in arm.joints} & {j.name for j in ee.joints}
    if clash:
        raise UserError(f"{config}: arm and end-effector share link/joint names {sorted(clash)}")
    arm = arm.with_mesh_prefix(f"parts/{arm.name}")
    ee = ee.with_mesh_prefix(f"parts/{ee.name}")
    mount = Joint(MOUNT_JOINT, "fixed", flange_link, EE_ROOT, np.eye(4))
    return RobotModel(config, arm.links + ee.links, arm.joints + [mount] + ee.joints)


def arm_links(model: RobotModel, ee_links: set[str]) -> list[str]:
    """The links that have a mesh and are not the end-effector's, in URDF order."""
    return [lk.name for lk in model.links if lk.visuals and lk.name not in ee_links]


@dataclass
class Robot:
    config: str
    arm: Arm
    ee: EndEffector
    model: RobotModel
    urdf: Path

    def __post_init__(self):
        self.kinematics = Kinematics(self.model)

    ee_root = EE_ROOT

    @property
    def ee_links(self) -> list[str]:
        """Links of the end-effector: `ee_mount` and everything below it."""
        out, frontier = [EE_ROOT], [EE_ROOT]
        while frontier:
            parent = frontier.pop()
            for j in self.model.joints:
                if j.parent == parent:
                    out.append(j.child)
                    frontier.append(j.child)
        return out

    @property
    def arm_links(self) -> list[str]:
        """The arm's links that have a mesh, in URDF order: the robot's parts besides the end-effector."""
        return arm_links(self.model, set(self.ee_links))

    @property
    def canonical(self) -> dict[str, float]:
        return dict(self.ee.canonical)

    def _q(self, q_arm) -> dict:
        q_arm = np.asarray(q_arm, dtype=float)
        if q_arm.shape[-1:] != (len(self.arm.joints),):
            raise UserError(f"{self.config}: expected {len(self.arm.joints)} arm joint values "
                            f"{list(self.arm.joints)}, got shape {q_arm.shape}")
        return {name: q_arm[..., i] for i, name in enumerate(self.arm.joints)}

    def T_base_link(self, q_arm) -> dict[str, np.ndarray]:
        poses = self.kinematics.link_poses({**self.canonical, **self._q(q_arm)})
        T_base_root = inv_T(poses[self.arm.base_link])
        return {name: T_base_root @ T for name, T in poses.items()}

    def T_base_ee(self, q_arm) -> np.ndarray:
        return self.T_base_link(q_arm)[EE_ROOT]


def load_robot(config: str, assets: Path | None = None) -> Robot:
    arm, ee = load_catalog().split(config)
    urdf = paths.config_urdf(config, assets)
    if not urdf.is_file():
        raise UserError(f"no URDF for {config} at {urdf}: build the robot assets with `make assets`")
    return Robot(config, arm, ee, read_urdf(urdf), urdf)
