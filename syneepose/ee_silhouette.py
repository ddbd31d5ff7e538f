"""The end-effector's occlusion-free silhouette (BOP's `mask`), rasterised from its meshes at pixel centres.

Cycles rendered it as a second view layer of the end-effector alone until issue 36: 0.15 s of a `mini`
frame's 0.9 s. The raster (feepe/raster.py: the meshes projected with the frame's K, pixel centres at
integers) takes 1.5 ms and gives the same mask: over 72 `mini` frames 5 of 107,383 pixels differ, all on
the outline, where a pixel centre lies on an edge to within the two renderers' rounding.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from feepe import raster
from syneepose.robots.model import RobotModel


class EeSilhouette:
    """The end-effector's visual meshes (those of `ee_links`), each with its link and origin."""

    def __init__(self, model: RobotModel, urdf_dir: Path, ee_links: set[str]):
        self.parts = []
        for link in model.links:
            if link.name not in ee_links:
                continue
            for visual in link.visuals:
                mesh = trimesh.load(str(Path(urdf_dir) / visual.mesh), force="mesh", process=False)
                self.parts.append((link.name, visual.origin, np.asarray(mesh.vertices, float),
                                   np.asarray(mesh.faces, np.int64)))

    def mask(self, T_base_link: dict[str, np.ndarray], T_cam_base: np.ndarray, K: np.ndarray,
             shape: tuple[int, int]) -> np.ndarray:
        """The pixel centres (H, W) that any of the meshes covers, posed by the links' base poses."""
        out = np.zeros(shape, bool)
        for link, origin, vertices, faces in self.parts:
            tri, _ = raster.triangles(vertices, faces, T_cam_base @ T_base_link[link] @ origin, K)
            out |= raster.mask(tri, shape)
        return out
