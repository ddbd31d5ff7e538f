"""Catalogue part -> RobotModel + meshes (arms keep their base; end-effectors get an `ee_mount` root)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh

from kernel.errors import UserError
from syneepose.robots.catalog import Arm, EndEffector, Part
from syneepose.robots.mjcf import read_mjcf
from syneepose.robots.model import RobotModel
from syneepose.robots.urdf_source import read_source_urdf

EE_ROOT = "ee_mount"
ARM_ROOT = "world"


def source_file(part: Part, source_root: Path) -> Path:
    return Path(source_root) / part.file


def convert_part(part: Part, source_root: Path) -> tuple[RobotModel, dict[str, trimesh.Trimesh]]:
    path = source_file(part, source_root)
    is_ee = isinstance(part, EndEffector)
    T_root_source = part.T_mount_source if is_ee else np.eye(4)
    if part.format == "mjcf":
        model, meshes = read_mjcf(path, part.name, EE_ROOT if is_ee else ARM_ROOT, T_root_source,
                                  part.compiler_angle)
    else:
        packages = {k: Path(source_root) / v for k, v in part.packages}
        keep_below = part.keep_below if isinstance(part, Arm) else None
        model, meshes = read_source_urdf(path, part.name, packages, keep_below,
                                         EE_ROOT if is_ee else None, T_root_source)
    if is_ee:
        model = _with_mimic(model, part)
    _check_named_links(model, part)
    return model, meshes


def _with_mimic(model: RobotModel, ee: EndEffector) -> RobotModel:
    names = {j.name: j for j in model.joints}
    joints = list(model.joints)
    for follower, mimic in ee.mimic:
        if follower not in names or mimic.joint not in names:
            raise UserError(f"end-effector {ee.name!r}: mimic table names a joint that the model lacks "
                            f"({follower!r} <- {mimic.joint!r}); joints are {sorted(names)}")
        i = next(k for k, j in enumerate(joints) if j.name == follower)
        joints[i] = replace(joints[i], mimic=mimic)
    for joint, value in ee.canonical:
        if joint not in names:
            raise UserError(f"end-effector {ee.name!r}: canonical configuration names unknown joint {joint!r}")
    return RobotModel(model.name, model.links, joints)


def _check_named_links(model: RobotModel, part: Part) -> None:
    links = {lk.name for lk in model.links}
    joints = {j.name for j in model.joints}
    if isinstance(part, Arm):
        for link in (part.base_link, part.flange_link):
            if link not in links:
                raise UserError(f"arm {part.name!r}: link {link!r} is not in the converted model")
        missing = [j for j in part.joints if j not in joints]
        if missing:
            raise UserError(f"arm {part.name!r}: joints {missing} are not in the converted model")
