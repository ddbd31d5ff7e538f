"""BOP `models_eval/`: each `models/` mesh resampled uniformly by Blender's Voxel Remesh (the BOP toolkit's
recipe), the dense vertex set that pose errors are computed on; with its own `models_info.json`."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import trimesh

from kernel.dataset import MODELS_INFO, model_name
from kernel.errors import UserError
from syneepose.robots.catalog import EndEffector
from syneepose.robots.ee_models import model_info, write_json, write_ply_mm

VOXEL_MM = 1.0  # BOP's default; measured: vertices 0.6-0.7 mm apart (median), visible surface kept to <= 0.04 mm
SHELL_MM = 2.0  # wall behind open shells (the Panda hand's body), two voxels: the thinnest the grid keeps


def _remesh_all(meshes_mm: list[tuple[np.ndarray, np.ndarray]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Child-process entry point: bpy is imported here only."""
    from syneepose.blender.remesh import voxel_remesh

    return [voxel_remesh(v, f, VOXEL_MM, SHELL_MM) for v, f in meshes_mm]


def eval_mesh(vertices_mm: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh:
    """The remeshed surface in metres: vertices unique as written (float32 mm), closed, normals outward."""
    verts, inv = np.unique(np.asarray(vertices_mm, np.float32), axis=0, return_inverse=True)
    faces = inv.reshape(-1)[faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    mesh = trimesh.Trimesh(verts.astype(np.float64) / 1000.0, faces, process=False)
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        raise UserError("voxel remesh gave an open or inconsistently wound surface; check the Blender version")
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def build_models_eval(models: Path, ees: list[EndEffector], out: Path) -> dict[str, int]:
    """Remesh `models/obj_*.ply` into `out` (in a spawned process: bpy holds global state); vertex counts."""
    sources = [trimesh.load(Path(models) / model_name(ee.obj_id), process=False) for ee in ees]
    with ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn")) as pool:
        remeshed = pool.submit(_remesh_all, [(m.vertices, m.faces) for m in sources]).result()
    infos, counts = {}, {}
    for ee, (verts, faces) in zip(ees, remeshed):
        mesh = eval_mesh(verts, faces)
        write_ply_mm(mesh, Path(out) / model_name(ee.obj_id))
        infos[str(ee.obj_id)] = model_info(mesh, ee)
        counts[ee.name] = len(mesh.vertices)
    write_json(infos, Path(out) / MODELS_INFO)
    return counts
