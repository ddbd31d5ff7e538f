"""The silhouette refinement's rasteriser (feepe/raster.py) against ray casting through Embree: the same
pixels, the same depths, the same sub-pixel coverage, also for a part that reaches behind the camera."""

import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from feepe import raster
from kernel.camera import backproject, project
from kernel.transforms import inv_T

K = np.array([[300.0, 0, 80], [0, 300.0, 60], [0, 0, 1]])
SHAPE = (120, 160)


def _meshes():
    rng = np.random.default_rng(3)
    blob = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    blob.vertices *= rng.uniform(0.7, 1.3, (len(blob.vertices), 1))  # uneven: rims inside the outline
    T = np.eye(4)
    T[:3, :3] = trimesh.transformations.euler_matrix(0.3, -0.4, 0.2)[:3, :3]
    T[:3, 3] = [0.01, -0.005, 0.5]
    bar = np.eye(4)
    bar[:3, 3] = [0.0513, 0.0037, 0.3]  # 2 m long: 0.7 m behind the camera to 1.3 m in front
    return [(blob, T), (trimesh.creation.capsule(0.08, 0.02), T), (trimesh.creation.box((0.04, 0.04, 2.0)), bar)]


def _cast(mesh: trimesh.Trimesh, T_cam_model: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Depth along the optical axis of the first hit of the ray through each image point (0: a miss)."""
    T_model_cam = inv_T(T_cam_model)
    rays = backproject(uv, np.ones(len(uv)), K) @ T_model_cam[:3, :3].T
    eye = np.broadcast_to(T_model_cam[:3, 3], rays.shape).copy()
    points, ray, _ = RayMeshIntersector(mesh).intersects_location(eye, rays, multiple_hits=False)
    z = np.zeros(len(uv))
    z[ray] = (points @ T_cam_model[:3, :3].T + T_cam_model[:3, 3])[:, 2]
    return z


def test_depth_equals_ray_casting_at_every_pixel_centre():
    for mesh, T in _meshes():
        vertices, faces = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
        depth = raster.render_depth(vertices, faces, T, K, SHAPE)
        v, u = np.mgrid[: SHAPE[0], : SHAPE[1]]
        cast = _cast(mesh, T, np.stack([u.ravel(), v.ravel()], 1).astype(float)).reshape(SHAPE)
        assert (depth > 0).sum() > 300
        assert ((depth > 0) != (cast > 0)).sum() <= 2  # a pixel centre exactly on a shared edge may go either way
        both = (depth > 0) & (cast > 0)
        assert np.abs(depth[both] - cast[both]).max() < 1e-9


def test_coverage_equals_ray_casting_at_sub_pixel_points():
    rng = np.random.default_rng(0)
    for mesh, T in _meshes():
        vertices, faces = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
        depth = raster.render_depth(vertices, faces, T, K, SHAPE)
        v, u = np.nonzero(depth > 0)
        uv = np.stack([u, v], 1) + rng.uniform(-3, 3, (len(u), 2))  # in, out and across the outline
        uv = uv[(uv >= 0).all(1) & (uv < SHAPE[::-1]).all(1)]  # beyond the image nothing is binned
        covered = raster.covered(raster.triangles(vertices, faces, T, K)[0], uv, SHAPE)
        hit = _cast(mesh, T, uv) > 0
        assert covered.sum() > 100 and (~covered).sum() > 50
        assert (covered == hit).all()


def test_the_near_plane_keeps_what_lies_in_front():
    mesh, T = _meshes()[2]
    P = (np.asarray(mesh.vertices) @ T[:3, :3].T + T[:3, 3])
    assert P[:, 2].min() < 0 < P[:, 2].max()
    depth = raster.render_depth(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64), T, K, SHAPE)
    assert depth[depth > 0].min() >= raster.NEAR_M
    assert (depth > 0).mean() > 0.1


def test_the_mask_of_image_triangles_is_the_z_buffers():
    for mesh, T in _meshes():
        vertices, faces = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
        depth = raster.render_depth(vertices, faces, T, K, SHAPE)
        assert np.array_equal(raster.mask(raster.triangles(vertices, faces, T, K)[0], SHAPE), depth > 0)


def test_compiled_projection_is_the_kernels_bit_for_bit():
    """to_pixel (the compiled loops' projection: triangles, rim samples, contour rows) = kernel.camera.project."""
    rng = np.random.default_rng(0)
    P = np.column_stack([rng.uniform(-0.5, 0.5, (1000, 2)), rng.uniform(-0.2, 3.0, 1000)])
    np.testing.assert_array_equal(raster._pixels(P, *K[[0, 1, 0, 1], [0, 1, 2, 2]]),
                                  project(P, K, min_z=raster.NEAR_M))
