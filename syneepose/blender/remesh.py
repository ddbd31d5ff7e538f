"""Blender's Voxel Remesh, done as the BOP toolkit's `scripts/remesh_models_for_eval_bpy.py` does it (preserve
volume, then triangulate), to resample a model uniformly for `models_eval/`. Imports bpy: call it only inside
a child process."""

from __future__ import annotations

import bpy
import numpy as np


def voxel_remesh(vertices: np.ndarray, faces: np.ndarray, voxel_size: float,
                 shell: float) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) of the remeshed surface, in the units of `vertices`. Before remeshing, every face
    is thickened by `shell` behind its normal (Solidify): an open surface has no inside for the voxel grid
    and would vanish; inside a closed part the added wall disappears in the union."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = bpy.data.meshes.new("model")
    mesh.from_pydata(np.asarray(vertices, float).tolist(), [], np.asarray(faces, int).tolist())
    obj = bpy.data.objects.new("model", mesh)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    solidify = obj.modifiers.new(name="Solidify", type="SOLIDIFY")
    solidify.thickness = shell
    solidify.offset = -1.0
    bpy.ops.object.modifier_apply(modifier=solidify.name)
    obj.data.remesh_voxel_size = voxel_size
    obj.data.use_remesh_preserve_volume = True
    bpy.ops.object.voxel_remesh()
    triangulate = obj.modifiers.new(name="Triangulate", type="TRIANGULATE")
    bpy.ops.object.modifier_apply(modifier=triangulate.name)
    out = obj.data
    verts = np.empty(len(out.vertices) * 3)
    out.vertices.foreach_get("co", verts)
    tris = np.empty(len(out.polygons) * 3, dtype=np.int64)
    out.polygons.foreach_get("vertices", tris)
    return verts.reshape(-1, 3), tris.reshape(-1, 3)
