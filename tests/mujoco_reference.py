"""MuJoCo on the original source files, as an independent FK reference for the converted URDFs."""

from pathlib import Path
from xml.etree import ElementTree as ET

import mujoco
import numpy as np

from syneepose.robots.mjcf import load_mujoco


def _urdf_skeleton(path: Path, packages: dict) -> mujoco.MjModel:
    """The source URDF without geometry (MuJoCo reads no Collada), fixed joints kept as bodies."""
    root = ET.parse(path).getroot()
    for link in root.findall("link"):
        for tag in ("visual", "collision"):
            for el in link.findall(tag):
                link.remove(el)
    ext = ET.SubElement(root, "mujoco")
    ET.SubElement(ext, "compiler", fusestatic="false", discardvisual="false")
    return mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))


def reference_model(part, source_root: Path) -> mujoco.MjModel:
    path = Path(source_root) / part.file
    if part.format == "mjcf":
        return load_mujoco(path, part.compiler_angle)
    return _urdf_skeleton(path, dict(part.packages))


def random_qpos(m: mujoco.MjModel, rng: np.random.Generator) -> dict:
    q = {}
    for j in range(m.njnt):
        lo, hi = m.jnt_range[j] if m.jnt_limited[j] else (-np.pi, np.pi)
        q[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)] = rng.uniform(lo, hi)
    return q


def link_frames(m: mujoco.MjModel, q: dict) -> dict:
    """World pose of each body's link frame (the body frame moved to its joint's anchor), by body name."""
    d = mujoco.MjData(m)
    for name, value in q.items():
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        d.qpos[m.jnt_qposadr[j]] = value
    mujoco.mj_kinematics(m, d)
    frames = {}
    for b in range(1, m.nbody):
        T = np.eye(4)
        T[:3, :3] = d.xmat[b].reshape(3, 3)
        joints = [j for j in range(m.njnt) if m.jnt_bodyid[j] == b]
        T[:3, 3] = d.xpos[b] + (T[:3, :3] @ m.jnt_pos[joints[0]] if joints else 0.0)
        frames[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b)] = T
    return frames
