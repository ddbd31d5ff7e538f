"""Source URDF (with Collada/STL/OBJ meshes) -> RobotModel.

Kinematics are copied; each visual mesh file is split into one mesh per sub-geometry with its own
colour, because Blender 5 no longer imports Collada and a URDF material holds one colour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from kernel.errors import UserError
from kernel.transforms import make_T, transform_points
from syneepose.robots.model import Joint, Link, RobotModel, Visual, read_urdf


def _resolve(filename: str, urdf_dir: Path, packages: dict[str, Path]) -> Path:
    if filename.startswith("package://"):
        package, _, rest = filename[len("package://"):].partition("/")
        if package not in packages:
            raise UserError(f"mesh {filename!r} names package {package!r}, which the catalogue does not map")
        return packages[package] / rest
    if filename.startswith("file://"):
        return Path(filename[len("file://"):])
    return urdf_dir / filename


def _rgba(geometry: trimesh.Trimesh, fallback) -> tuple[float, float, float, float]:
    visual = geometry.visual
    if visual.kind == "texture" and visual.material is not None:
        mat = visual.material
        color = getattr(mat, "baseColorFactor", None)
        if color is None:
            color = getattr(mat, "diffuse", None)
        if color is not None:
            return tuple(float(c) / 255.0 for c in np.asarray(color)[:4])
    if visual.kind == "face" or visual.kind == "vertex":
        return tuple(float(c) / 255.0 for c in visual.main_color[:4])
    return fallback


def _drop_below(model: RobotModel, link: str) -> RobotModel:
    """Keep `link` but nothing attached below it."""
    removed, frontier = set(), [link]
    while frontier:
        parent = frontier.pop()
        for j in model.joints:
            if j.parent == parent and j.child not in removed:
                removed.add(j.child)
                frontier.append(j.child)
    links = [lk for lk in model.links if lk.name not in removed]
    joints = [j for j in model.joints if j.child not in removed]
    return RobotModel(model.name, links, joints)


def read_source_urdf(path: Path, name: str, packages: dict[str, Path], keep_below: str | None = None,
                     root_link: str | None = None, T_root_source: np.ndarray = np.eye(4),
                     ) -> tuple[RobotModel, dict[str, trimesh.Trimesh]]:
    """Convert; with `root_link`, a new root carrying the source root at `T_root_source`."""
    import yourdfpy

    path = Path(path)
    source = read_urdf(path, check_meshes=False)
    urdf = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)
    scales = {
        (ul.name, k): (np.ones(3) if uv.geometry.mesh.scale is None else np.broadcast_to(uv.geometry.mesh.scale, 3))
        for ul in urdf.robot.links for k, uv in enumerate(ul.visuals)
    }
    if keep_below:
        source = _drop_below(source, keep_below)
    meshes: dict[str, trimesh.Trimesh] = {}
    links = []
    for link in source.links:
        visuals = []
        for k, visual in enumerate(link.visuals):
            file = _resolve(visual.mesh, path.parent, packages)
            if not file.is_file():
                raise UserError(f"{path}: mesh {visual.mesh!r} of link {link.name!r} not found at {file}")
            scene = trimesh.load(str(file), force="scene")
            S = make_T()
            S[:3, :3] = np.diag(scales[(link.name, k)])
            scaled = not np.allclose(S, np.eye(4))
            for i, node in enumerate(scene.graph.nodes_geometry):
                T_node, geom_name = scene.graph[node]
                geometry = scene.geometry[geom_name]
                # Node transform and scale are baked into the vertices: a URDF origin is rigid.
                key = f"meshes/{file.stem}_{i}{'_scaled' if scaled else ''}.ply"
                if key not in meshes:
                    vertices = transform_points(S @ T_node, np.asarray(geometry.vertices, dtype=float))
                    meshes[key] = trimesh.Trimesh(vertices, geometry.faces, process=False)
                rgba = _rgba(geometry, visual.rgba)
                visuals.append(Visual(key, visual.origin, rgba, f"{link.name}_{k}_{i}"))
        links.append(Link(link.name, visuals))
    joints = list(source.joints)
    if root_link:
        links.insert(0, Link(root_link))
        joints.insert(0, Joint(f"{root_link}_to_{source.root}", "fixed", root_link, source.root, T_root_source))
    return RobotModel(name, links, joints), meshes
