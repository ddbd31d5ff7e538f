"""A robot as plain data (links, joints, visuals) and its URDF form.

Every converter produces a `RobotModel`; every consumer (FK, renderer, BOP models) reads one back from
URDF with `read_urdf`, so the URDF on disk is the single source of truth.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from kernel.errors import UserError
from kernel.transforms import R_to_rpy
from kernel.urdf import links_below

JOINT_TYPES = ("fixed", "revolute", "continuous", "prismatic")


@dataclass
class Mimic:
    joint: str
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass
class Visual:
    mesh: str  # path relative to the URDF file
    origin: np.ndarray  # 4x4 pose of the mesh frame in the link frame
    rgba: tuple[float, float, float, float]
    name: str = ""


@dataclass
class Link:
    name: str
    visuals: list[Visual] = field(default_factory=list)


@dataclass
class Joint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray  # 4x4 pose of the child link frame in the parent link frame at q = 0
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    lower: float | None = None
    upper: float | None = None
    mimic: Mimic | None = None


@dataclass
class RobotModel:
    name: str
    links: list[Link]
    joints: list[Joint]

    def link(self, name: str) -> Link:
        for link in self.links:
            if link.name == name:
                return link
        raise KeyError(name)

    def joint(self, name: str) -> Joint:
        for joint in self.joints:
            if joint.name == name:
                return joint
        raise KeyError(name)

    @property
    def root(self) -> str:
        children = {j.child for j in self.joints}
        roots = [link.name for link in self.links if link.name not in children]
        if len(roots) != 1:
            raise ValueError(f"robot {self.name!r} has {len(roots)} root links: {roots}")
        return roots[0]

    def with_mesh_prefix(self, prefix: str) -> RobotModel:
        """Same robot with every mesh path re-rooted, for a URDF written in another folder."""
        links = [
            Link(link.name, [replace(v, mesh=f"{prefix}/{v.mesh}") for v in link.visuals]) for link in self.links
        ]
        return RobotModel(self.name, links, self.joints)


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(values))


def _origin_element(parent: ET.Element, T: np.ndarray) -> None:
    ET.SubElement(parent, "origin", xyz=_fmt(T[:3, 3]), rpy=_fmt(R_to_rpy(T[:3, :3])))


def urdf_string(model: RobotModel) -> str:
    robot = ET.Element("robot", name=model.name)
    for link in model.links:
        el = ET.SubElement(robot, "link", name=link.name)
        for visual in link.visuals:
            v = ET.SubElement(el, "visual", name=visual.name) if visual.name else ET.SubElement(el, "visual")
            _origin_element(v, visual.origin)
            geom = ET.SubElement(v, "geometry")
            ET.SubElement(geom, "mesh", filename=visual.mesh)
            mat = ET.SubElement(v, "material", name="rgba_" + "_".join(f"{c:.4f}" for c in visual.rgba))
            ET.SubElement(mat, "color", rgba=_fmt(visual.rgba))
    for joint in model.joints:
        el = ET.SubElement(robot, "joint", name=joint.name, type=joint.type)
        ET.SubElement(el, "parent", link=joint.parent)
        ET.SubElement(el, "child", link=joint.child)
        _origin_element(el, joint.origin)
        if joint.type != "fixed":
            ET.SubElement(el, "axis", xyz=_fmt(joint.axis))
        if joint.type in ("revolute", "prismatic"):
            ET.SubElement(el, "limit", lower=repr(float(joint.lower)), upper=repr(float(joint.upper)),
                          effort="0", velocity="0")
        if joint.mimic is not None:
            ET.SubElement(el, "mimic", joint=joint.mimic.joint, multiplier=repr(float(joint.mimic.multiplier)),
                          offset=repr(float(joint.mimic.offset)))
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def write_urdf(model: RobotModel, path: Path) -> None:
    """Atomic: a reader never sees a half-written URDF."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(urdf_string(model))
    os.replace(tmp, path)


def read_urdf(path: Path, check_meshes: bool = True) -> RobotModel:
    """Parse with yourdfpy (kinematics and visuals only) into a RobotModel."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"URDF {path} does not exist: build the robot assets with `make assets`")
    urdf = _load(path, "rebuild it with `make assets`")
    links = [Link(ul.name, [_visual(uv, ul.name, path, _mesh_beside(uv, path) if check_meshes else None,
                                    "rebuild with `make assets`") for uv in ul.visuals]) for ul in urdf.robot.links]
    return RobotModel(urdf.robot.name, links, [_joint(uj, path) for uj in urdf.robot.joints])


def read_urdf_below(path: Path, root_link: str, mesh_path) -> RobotModel:
    """The part of a user's URDF from `root_link` down (an end-effector), rooted there, with every mesh path
    absolute as `mesh_path(filename)` resolves it (package:// paths); visuals of other links are not read."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"no URDF at {path}: pass --urdf with the robot's URDF file")
    urdf = _load(path, "check the file")
    names = [ul.name for ul in urdf.robot.links]
    if root_link not in names:
        raise UserError(f"--ee-link {root_link!r} is not a link of {path.name}; its links: {', '.join(names)}")
    below = links_below(root_link, [(uj.parent, uj.child) for uj in urdf.robot.joints])
    links = []
    for ul in urdf.robot.links:
        if ul.name in below:
            visuals = []
            for uv in ul.visuals:
                mesh = Path(mesh_path(uv.geometry.mesh.filename)) if _has_mesh(uv) else None
                visual = _visual(uv, ul.name, path, mesh, "pass --mesh-dir with the folder package:// paths start from")
                visuals.append(replace(visual, mesh=str(mesh)))
            links.append(Link(ul.name, visuals))
    joints = [_joint(uj, path) for uj in urdf.robot.joints if uj.parent in below and uj.child in below]
    return RobotModel(f"{urdf.robot.name}_{root_link}", links, joints)


def _load(path: Path, mend: str):
    import yourdfpy

    try:
        return yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)
    except Exception as exc:  # yourdfpy raises bare lxml / ValueError types
        raise UserError(f"URDF {path} cannot be parsed ({exc}): {mend}") from exc


def _has_mesh(uv) -> bool:
    return uv.geometry is not None and uv.geometry.mesh is not None


def _mesh_beside(uv, path: Path) -> Path | None:
    return path.parent / uv.geometry.mesh.filename if _has_mesh(uv) else None


def _visual(uv, link: str, path: Path, mesh_file: Path | None, mend: str) -> Visual:
    """`mesh_file`: where the mesh must be (None: not checked)."""
    if not _has_mesh(uv):
        raise UserError(f"URDF {path}: link {link!r} has a non-mesh visual; only meshes are supported")
    if mesh_file is not None and not Path(mesh_file).is_file():
        raise UserError(f"URDF {path}: mesh {uv.geometry.mesh.filename!r} of link {link!r} is missing (looked at "
                        f"{mesh_file}): {mend}")
    rgba = (0.7, 0.7, 0.7, 1.0)
    if uv.material is not None and uv.material.color is not None:
        rgba = tuple(float(c) for c in uv.material.color.rgba)
    origin = np.eye(4) if uv.origin is None else np.asarray(uv.origin, dtype=float)
    return Visual(uv.geometry.mesh.filename, origin, rgba, uv.name or "")


def _joint(uj, path: Path) -> Joint:
    if uj.type not in JOINT_TYPES:
        raise UserError(f"URDF {path}: joint {uj.name!r} has unsupported type {uj.type!r}")
    mimic = None if uj.mimic is None else Mimic(uj.mimic.joint, float(uj.mimic.multiplier or 1.0),
                                                float(uj.mimic.offset or 0.0))
    lower = upper = None
    if uj.limit is not None and uj.type in ("revolute", "prismatic"):
        lower, upper = float(uj.limit.lower), float(uj.limit.upper)
    axis = np.array([1.0, 0.0, 0.0]) if uj.axis is None else np.asarray(uj.axis, dtype=float)
    origin = np.eye(4) if uj.origin is None else np.asarray(uj.origin, dtype=float)
    return Joint(uj.name, uj.type, uj.parent, uj.child, origin, axis, lower, upper, mimic)
