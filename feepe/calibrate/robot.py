"""The user's robot from its URDF (yourdfpy): which joints move the arm, the arm links' meshes, and per frame
the end-effector's and the arm links' poses in the base frame. No generator needed: any URDF whose meshes
trimesh reads (package:// paths are looked up beside the URDF and in --mesh-dir)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
import yourdfpy

from kernel.errors import UserError
from kernel.transforms import inv_T
from kernel.urdf import links_below, mesh_path


@dataclass
class LinkPoses:
    """One frame's forward kinematics, metres, base frame."""
    T_base_ee: np.ndarray  # (4, 4)
    T_base_links: np.ndarray  # (n, 4, 4), in the order of UrdfRobot.arm_links


class UrdfRobot:
    """`ee_link`: the link whose frame is the end-effector model's frame (its templates and .ply);
    `base_link`: the frame the calibration is given in (default: the URDF's root)."""

    def __init__(self, urdf: Path, ee_link: str, base_link: str | None = None, mesh_dir: Path | None = None):
        urdf = Path(urdf)
        if not urdf.is_file():
            raise UserError(f"no URDF at {urdf}: pass --urdf with the robot's URDF file")
        self.urdf, self.mesh_dir = urdf, mesh_dir
        try:
            self.model = yourdfpy.URDF.load(str(urdf), build_scene_graph=True, load_meshes=False,
                                            filename_handler=self._mesh_path)
        except Exception as exc:  # yourdfpy raises lxml's and its own errors for an unreadable file
            raise UserError(f"{urdf} is not a URDF yourdfpy reads ({type(exc).__name__}: {exc})") from None
        links = [link.name for link in self.model.robot.links]
        for flag, name in (("--ee-link", ee_link), ("--base-link", base_link)):
            if name is not None and name not in links:
                raise UserError(f"{flag} {name!r} is not a link of {urdf.name}; its links: {', '.join(links)}")
        self.ee_link, self.base_link = ee_link, base_link or self.model.base_link
        ee_side = links_below(ee_link, [(j.parent, j.child) for j in self.model.robot.joints])
        if self.base_link in ee_side:
            raise UserError(f"--base-link {self.base_link!r} lies on the end-effector (below {ee_link!r})")
        self.arm_links = [link.name for link in self.model.robot.links
                          if link.visuals and link.name not in ee_side and self._has_meshes(link)]
        movers = {j.name for j in self.model.robot.joints if j.child not in ee_side}
        self.arm_joints = [name for name in self.model.actuated_joint_names if name in movers]

    def _mesh_path(self, name: str) -> str:
        return str(mesh_path(name, self.urdf, self.mesh_dir))

    @staticmethod
    def _has_meshes(link) -> bool:
        return any(v.geometry is not None and v.geometry.mesh is not None for v in link.visuals)

    def mesh_paths(self, link: str) -> list[Path]:
        return [Path(self._mesh_path(v.geometry.mesh.filename)) for v in self.model.link_map[link].visuals
                if v.geometry is not None and v.geometry.mesh is not None]

    def link_mesh(self, link: str) -> trimesh.Trimesh:
        """The link's visual meshes in its link frame (metres, with the URDF's scale)."""
        parts = []
        for visual in self.model.link_map[link].visuals:
            mesh = visual.geometry.mesh if visual.geometry is not None else None
            if mesh is None:
                continue
            path = Path(self._mesh_path(mesh.filename))
            if not path.is_file():
                raise UserError(f"link {link!r}: mesh {mesh.filename} not found (looked at {path}); "
                                "pass --mesh-dir with the folder its package:// paths start from")
            part = trimesh.load(str(path), force="mesh")
            if mesh.scale is not None:
                part.apply_scale(mesh.scale)
            origin = visual.origin if visual.origin is not None else np.eye(4)
            parts.append(part.apply_transform(origin))
        return trimesh.util.concatenate(parts)

    def poses(self, joints: dict[str, float]) -> LinkPoses:
        """Forward kinematics of one frame's joint positions (by name; joints past the end-effector link
        are not read). A joint of the arm missing is a UserError naming it."""
        missing = [name for name in self.arm_joints if name not in joints]
        if missing:
            raise UserError(f"joint states lack the arm joint(s) {', '.join(missing)} of {self.urdf.name}; "
                            "record every joint between the base and the end-effector link")
        self.model.update_cfg({name: float(joints[name]) for name in self.arm_joints})
        T_root_base = self.model.get_transform(self.base_link)
        T_base_root = inv_T(T_root_base)
        T = lambda link: T_base_root @ self.model.get_transform(link)
        return LinkPoses(T(self.ee_link), np.stack([T(link) for link in self.arm_links]) if self.arm_links
                         else np.zeros((0, 4, 4)))
