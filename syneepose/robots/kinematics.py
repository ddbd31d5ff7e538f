"""Forward kinematics over a RobotModel, batched over frames.

`q` is a mapping joint name -> value (scalar or array of shape (N,)). Joints left out take the
model's default (0, or the value a caller passes as `defaults`); mimic joints follow their master
unless given explicitly, so a test can drive every joint independently.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from kernel.errors import UserError
from kernel.transforms import axis_angle_to_R
from syneepose.robots.model import RobotModel


class Kinematics:
    def __init__(self, model: RobotModel):
        self.model = model
        self.root = model.root
        self._by_child = {j.child: j for j in model.joints}
        self._order = self._topological_joints()
        self.joint_names = [j.name for j in self._order if j.type != "fixed"]
        self.actuated = [j.name for j in self._order if j.type != "fixed" and j.mimic is None]
        self._joints = {j.name: j for j in model.joints}
        for j in model.joints:
            if j.mimic is not None and j.mimic.joint not in self._joints:
                raise UserError(f"robot {model.name!r}: joint {j.name!r} mimics unknown joint {j.mimic.joint!r}")

    def _topological_joints(self):
        children: dict[str, list] = {}
        for j in self.model.joints:
            children.setdefault(j.parent, []).append(j)
        order, stack = [], [self.root]
        while stack:
            link = stack.pop()
            for j in children.get(link, []):
                order.append(j)
                stack.append(j.child)
        if len(order) != len(self.model.joints):
            raise UserError(f"robot {self.model.name!r}: joints do not form one tree under {self.root!r}")
        return order

    def joint_values(self, q: Mapping[str, object], defaults: Mapping[str, float] | None = None) -> dict:
        unknown = set(q) - set(self.joint_names)
        if unknown:
            raise UserError(f"robot {self.model.name!r} has no joints {sorted(unknown)}; it has {self.joint_names}")
        values = {}
        defaults = defaults or {}
        for name in self.actuated:
            values[name] = np.asarray(q.get(name, defaults.get(name, 0.0)), dtype=float)
        for name in self.joint_names:
            joint = self._joints[name]
            if joint.mimic is None:
                continue
            if name in q:
                values[name] = np.asarray(q[name], dtype=float)
            else:
                master = values[joint.mimic.joint]
                values[name] = joint.mimic.multiplier * master + joint.mimic.offset
        return values

    def link_poses(self, q: Mapping[str, object], defaults: Mapping[str, float] | None = None) -> dict:
        """Pose of every link in the root frame: name -> (..., 4, 4)."""
        values = self.joint_values(q, defaults)
        batch = np.broadcast_shapes(*(np.shape(v) for v in values.values())) if values else ()
        poses = {self.root: np.broadcast_to(np.eye(4), batch + (4, 4))}
        for joint in self._order:
            T = poses[joint.parent] @ joint.origin
            if joint.type in ("revolute", "continuous"):
                motion = np.zeros(batch + (4, 4))
                motion[..., :3, :3] = axis_angle_to_R(joint.axis, np.broadcast_to(values[joint.name], batch))
                motion[..., 3, 3] = 1.0
                T = T @ motion
            elif joint.type == "prismatic":
                motion = np.broadcast_to(np.eye(4), batch + (4, 4)).copy()
                axis = joint.axis / np.linalg.norm(joint.axis)
                motion[..., :3, 3] = np.broadcast_to(values[joint.name], batch)[..., None] * axis
                T = T @ motion
            poses[joint.child] = T
        return poses

    def pose(self, link: str, q: Mapping[str, object], defaults: Mapping[str, float] | None = None) -> np.ndarray:
        poses = self.link_poses(q, defaults)
        if link not in poses:
            raise UserError(f"robot {self.model.name!r} has no link {link!r}")
        return poses[link]
