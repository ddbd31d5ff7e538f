"""MJCF -> RobotModel, through MuJoCo's own compiler.

MuJoCo resolves defaults, classes, `ref`, quat/euler/axisangle and mesh recentring for us: we compile
the model, pose it at qpos = 0 and read world frames. One URDF link per body, its frame at the joint
anchor (the body frame when the body has no joint), so URDF q = 0 is MuJoCo qpos = 0 (`ref` honoured).
Visual geoms are those that collide with nothing (contype = conaffinity = 0); their meshes keep
MuJoCo's compiled vertices, with the geom pose as the URDF visual origin.
"""

from __future__ import annotations

import os
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import trimesh

from kernel.errors import UserError
from kernel.transforms import inv_T, make_T
from syneepose.robots.model import Joint, Link, RobotModel, Visual


def patched_mjcf(path: Path, compiler_angle: str | None = None) -> Path:
    """Write `<stem>.syneepose.xml` beside `path` with the fixes a standalone load needs.

    - `compiler_angle`: robosuite grippers are fragments merged into a model that declares radians;
      loaded alone MuJoCo would read their angles as degrees.
    - a mesh asset whose name repeats an earlier one is dropped (robosuite's 2F-85 lists one twice,
      the second pointing at a file it does not ship).
    """
    path = Path(path)
    if not path.is_file():
        raise UserError(f"MJCF {path} does not exist: the source extraction is incomplete; delete it and rerun")
    root = ET.parse(path).getroot()
    if compiler_angle:
        compiler = root.find("compiler")
        if compiler is None:
            compiler = ET.Element("compiler")
            root.insert(0, compiler)
        compiler.set("angle", compiler_angle)
    for asset in root.findall("asset"):
        seen = set()
        for mesh in list(asset.findall("mesh")):
            name = mesh.get("name") or Path(mesh.get("file", "")).stem
            if name in seen:
                asset.remove(mesh)
            seen.add(name)
    out = path.with_name(f"{path.stem}.syneepose.xml")
    tmp = out.with_name(f".{out.name}.tmp{os.getpid()}")
    tmp.write_text(ET.tostring(root, encoding="unicode"))
    os.replace(tmp, out)
    return out


def load_mujoco(path: Path, compiler_angle: str | None = None):
    import mujoco

    patched = patched_mjcf(path, compiler_angle)
    try:
        return mujoco.MjModel.from_xml_path(str(patched))
    except ValueError as exc:
        raise UserError(f"MuJoCo cannot compile {path}: {exc}") from exc


def _primitive_mesh(m, g: int) -> trimesh.Trimesh:
    import mujoco

    size = m.geom_size[g]
    kind = m.geom_type[g]
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return trimesh.creation.box(extents=2 * size)
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return trimesh.creation.icosphere(subdivisions=3, radius=size[0])
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return trimesh.creation.cylinder(radius=size[0], height=2 * size[1], sections=48)
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return trimesh.creation.capsule(radius=size[0], height=2 * size[1], count=[48, 24])
    raise UserError(f"visual geom {g} has type {kind}, which the converter does not support")


def _mesh(m, mesh_id: int) -> trimesh.Trimesh:
    va, vn = m.mesh_vertadr[mesh_id], m.mesh_vertnum[mesh_id]
    fa, fn = m.mesh_faceadr[mesh_id], m.mesh_facenum[mesh_id]
    return trimesh.Trimesh(m.mesh_vert[va:va + vn].astype(float), m.mesh_face[fa:fa + fn], process=False)


def read_mjcf(path: Path, name: str, root_link: str, T_root_world: np.ndarray = np.eye(4),
              compiler_angle: str | None = None) -> tuple[RobotModel, dict[str, trimesh.Trimesh]]:
    """Convert; `T_root_world` places the MJCF world frame in the new root link."""
    import mujoco

    m = load_mujoco(path, compiler_angle)
    d = mujoco.MjData(m)
    d.qpos[:] = 0.0
    mujoco.mj_kinematics(m, d)

    def obj_name(kind, i, fallback):
        return mujoco.mj_id2name(m, kind, i) or fallback

    link_names = {0: root_link}
    T_world_link = {0: inv_T(T_root_world)}
    links = [Link(root_link)]
    joints, meshes = [], {}
    for b in range(1, m.nbody):
        lname = obj_name(mujoco.mjtObj.mjOBJ_BODY, b, f"body{b}")
        link_names[b] = lname
        body_joints = [j for j in range(m.njnt) if m.jnt_bodyid[j] == b]
        if len(body_joints) > 1:
            raise UserError(f"{path}: body {lname!r} has {len(body_joints)} joints; one per body is supported")
        R = d.xmat[b].reshape(3, 3)
        if body_joints:
            j = body_joints[0]
            T = make_T(R, d.xanchor[j])
        else:
            T = make_T(R, d.xpos[b])
        T_world_link[b] = T
        parent = m.body_parentid[b]
        origin = inv_T(T_world_link[parent]) @ T
        if body_joints:
            j = body_joints[0]
            jname = obj_name(mujoco.mjtObj.mjOBJ_JOINT, j, f"joint{j}")
            kind = m.jnt_type[j]
            limited = bool(m.jnt_limited[j])
            if kind == mujoco.mjtJoint.mjJNT_HINGE:
                jtype = "revolute" if limited else "continuous"
            elif kind == mujoco.mjtJoint.mjJNT_SLIDE:
                jtype = "prismatic"
                if not limited:
                    raise UserError(f"{path}: slide joint {jname!r} has no range; URDF needs limits")
            else:
                raise UserError(f"{path}: joint {jname!r} is a ball or free joint; the converter needs hinges/slides")
            axis = R.T @ d.xaxis[j]
            lower, upper = (float(m.jnt_range[j][0]), float(m.jnt_range[j][1])) if limited else (None, None)
            joints.append(Joint(jname, jtype, link_names[parent], lname, origin, axis, lower, upper))
        else:
            joints.append(Joint(f"{link_names[parent]}_to_{lname}", "fixed", link_names[parent], lname, origin))
        visuals = []
        for g in np.flatnonzero(m.geom_bodyid == b):
            if m.geom_contype[g] != 0 or m.geom_conaffinity[g] != 0:
                continue
            gname = obj_name(mujoco.mjtObj.mjOBJ_GEOM, g, f"{lname}_geom{g}")
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
                mesh_id = m.geom_dataid[g]
                key = f"meshes/{obj_name(mujoco.mjtObj.mjOBJ_MESH, mesh_id, f'mesh{mesh_id}')}.ply"
                if key not in meshes:
                    meshes[key] = _mesh(m, mesh_id)
            else:
                key = f"meshes/{gname}.ply"
                meshes[key] = _primitive_mesh(m, g)
            rgba = m.mat_rgba[m.geom_matid[g]] if m.geom_matid[g] >= 0 else m.geom_rgba[g]
            T_geom = make_T(d.geom_xmat[g].reshape(3, 3), d.geom_xpos[g])
            visuals.append(Visual(key, inv_T(T) @ T_geom, tuple(float(c) for c in rgba), gname))
        links.append(Link(lname, visuals))
    return RobotModel(name, links, joints), meshes
