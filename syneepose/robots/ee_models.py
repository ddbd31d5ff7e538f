"""End-effector rigid models: the mesh at the canonical finger configuration, in the `ee_mount`
frame, written as BOP `models/obj_XXXXXX.ply` (millimetres, outward unit vertex normals, vertex colours) +
`models_info.json`."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import trimesh

from kernel.errors import UserError
from syneepose.robots.catalog import EndEffector
from syneepose.robots.kinematics import Kinematics
from syneepose.robots.model import RobotModel, read_urdf
from syneepose.robots.symmetry import check_symmetry, diameter, symmetry_transforms


def rigid_mesh(model: RobotModel, urdf_dir: Path, canonical: dict[str, float]) -> trimesh.Trimesh:
    """All visuals posed by FK and merged, with each visual's colour on its vertices (metres)."""
    poses = Kinematics(model).link_poses(canonical)
    parts = []
    for link in model.links:
        for visual in link.visuals:
            mesh = trimesh.load(str(Path(urdf_dir) / visual.mesh), force="mesh", process=False)
            mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
            mesh.apply_transform(poses[link.name] @ visual.origin)
            rgba = np.clip(np.round(np.asarray(visual.rgba) * 255), 0, 255).astype(np.uint8)
            mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile(rgba, (len(mesh.vertices), 1)))
            parts.append(mesh)
    if not parts:
        raise UserError(f"end-effector {model.name!r} has no visual meshes")
    return trimesh.util.concatenate(parts)


def load_ee_mesh(ee: EndEffector, part_urdf: Path) -> trimesh.Trimesh:
    return rigid_mesh(read_urdf(part_urdf), Path(part_urdf).parent, dict(ee.canonical))


def orient_outward(mesh: trimesh.Trimesh, n_rays: int = 50000, seed: int = 0) -> trimesh.Trimesh:
    """The same vertices and faces, with faces flipped so that each connected component (vertices welded by
    position) is consistently wound and faces the outside: the side that rays from a surrounding sphere hit
    first. A component no ray reaches (an internal cavity) keeps the source's orientation (the majority by
    area). Some sources mix inward faces: the Shadow Hand's palm, the Robotiq 3-finger's links."""
    uniq, inv = trimesh.grouping.unique_rows(mesh.vertices, digits=8)
    welded = trimesh.Trimesh(mesh.vertices[uniq], inv[mesh.faces], process=False)
    vote = _outside_votes(welded, n_rays, seed)
    area = welded.area_faces
    flip = np.zeros(len(welded.faces), dtype=bool)
    for comp in trimesh.graph.connected_components(welded.face_adjacency, nodes=np.arange(len(welded.faces)),
                                                   min_len=1):
        part = welded.submesh([comp], append=True)
        if not part.is_winding_consistent:
            before = part.faces.copy()
            trimesh.repair.fix_winding(part)
            flip[comp] = ~(part.faces == before).all(axis=1)
        v = vote[comp].sum()
        if v < 0 or (v == 0 and area[comp][flip[comp]].sum() > area[comp][~flip[comp]].sum()):
            flip[comp] = ~flip[comp]
    faces = mesh.faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    return trimesh.Trimesh(mesh.vertices, faces, vertex_colors=mesh.visual.vertex_colors, process=False)


def _outside_votes(mesh: trimesh.Trimesh, n_rays: int, seed: int) -> np.ndarray:
    """Per face: (rays hitting it first from its front) - (from its back); rays come from a sphere around
    the mesh and aim at area-uniform surface samples."""
    rng = np.random.default_rng(seed)
    radius = np.linalg.norm(mesh.extents)
    dirs = rng.normal(size=(n_rays, 3))
    origins = mesh.bounds.mean(axis=0) + radius * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    targets, _ = trimesh.sample.sample_surface(mesh, n_rays, seed=seed)
    rays = targets - origins
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    tri, ray = mesh.ray.intersects_id(origins, rays, multiple_hits=False)
    vote = np.zeros(len(mesh.faces))
    np.add.at(vote, tri, -np.sign(np.einsum("ij,ij->i", mesh.face_normals[tri], rays[ray])))
    return vote


def model_info(mesh_m: trimesh.Trimesh, ee: EndEffector) -> dict:
    """BOP models_info entry (mm). Claimed symmetries must hold on the mesh, else an error."""
    lo, hi = mesh_m.bounds * 1000.0
    info = {
        "diameter": diameter(mesh_m) * 1000.0,
        "min_x": lo[0], "min_y": lo[1], "min_z": lo[2],
        "size_x": hi[0] - lo[0], "size_y": hi[1] - lo[1], "size_z": hi[2] - lo[2],
    }
    discrete, continuous = [], []
    for axis, order in ee.symmetries:
        holds, err = check_symmetry(mesh_m, axis, order)
        if not holds:
            raise UserError(f"end-effector {ee.name!r}: claimed symmetry (axis {axis}, order {order}) does not "
                            f"hold: mean surface error {err:.2%} of the diameter > 1%; fix the catalogue")
        if order == 0:
            continuous.append({"axis": [float(axis == a) for a in "xyz"], "offset": [0.0, 0.0, 0.0]})
        else:
            for T in symmetry_transforms(axis, order):
                T_mm = T.copy()
                T_mm[:3, 3] *= 1000.0
                discrete.append([float(v) for v in T_mm.ravel()])
    if discrete:
        info["symmetries_discrete"] = discrete
    if continuous:
        info["symmetries_continuous"] = continuous
    return {k: (float(v) if isinstance(v, (np.floating, float)) else v) for k, v in info.items()}


def write_ply_mm(mesh_m: trimesh.Trimesh, path: Path) -> None:
    """Binary PLY in mm with `nx ny nz` (angle-weighted face normals, unit; bop_toolkit's renderer needs them)
    and the vertex colours when the mesh has them. Normals come from the float32 vertices as written, so a
    reader recomputing them from the file gets the same."""
    mesh = trimesh.Trimesh((mesh_m.vertices * 1000.0).astype(np.float32), mesh_m.faces, process=False)
    if mesh_m.visual.kind == "vertex":
        mesh.visual.vertex_colors = mesh_m.visual.vertex_colors
    tmp = Path(path).with_name(f".{Path(path).name}.tmp{os.getpid()}")
    tmp.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=True,
                                                    include_attributes=False))
    os.replace(tmp, path)


def write_json(data, path: Path) -> None:
    tmp = Path(path).with_name(f".{Path(path).name}.tmp{os.getpid()}")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True))
    os.replace(tmp, path)
