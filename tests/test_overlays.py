"""Pose overlays on the tiny rendered set: the model projected at the ground-truth pose outlines the rendered
mask (mean contour distance <= 1 px), a wrong estimate is drawn where the model would be, and the zoomed view
keeps the geometry; the silhouette (FEEPE's rasteriser) against the triangle fill it replaced."""

import cv2
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from eval.overlays import EST_COLOUR, Mesh, draw_pose, load_mesh, silhouette, zoom
from kernel.bop import read_frame, read_scene, split_dir
from kernel.camera import project
from kernel.drawing import GT_COLOUR
from kernel.transforms import make_T, transform_points


def _frames(root):
    for scene_dir in sorted(split_dir(root).iterdir()):
        meta, im_ids = read_scene(scene_dir)
        mesh = load_mesh(root / "models" / f"obj_{meta.obj_id:06d}.ply")
        for im_id in im_ids:
            yield mesh, read_frame(scene_dir, im_id)


def _contour_points(mask: np.ndarray) -> np.ndarray:
    """(n, 2) x, y of every boundary pixel of `mask`, holes included."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    return np.concatenate([c[:, 0] for c in contours]) if contours else np.zeros((0, 2), int)


def _distance_to_boundary(mask: np.ndarray) -> np.ndarray:
    """Per pixel, the distance (px) to the nearest boundary pixel of `mask`."""
    not_boundary = np.ones(mask.shape, np.uint8)
    xy = _contour_points(mask)
    not_boundary[xy[:, 1], xy[:, 0]] = 0
    return cv2.distanceTransform(not_boundary, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def test_contour_at_ground_truth_pose_lies_on_the_mask_boundary(tiny_dataset):
    distances = []
    for mesh, frame in _frames(tiny_dataset):
        projected = silhouette(mesh, frame.K, frame.T_cam_ee, frame.mask.shape)
        xy = _contour_points(projected)
        distances.append(_distance_to_boundary(frame.mask)[xy[:, 1], xy[:, 0]].mean())
        assert (projected & frame.mask).sum() / (projected | frame.mask).sum() > 0.9
    assert len(distances) == 12 and max(distances) <= 1.0, distances


def test_estimate_and_ground_truth_in_their_colours(tiny_dataset):
    mesh, frame = next(_frames(tiny_dataset))
    truth_only = draw_pose(frame.rgb, frame.mask, frame.K, mesh, None)
    assert (truth_only == GT_COLOUR).all(axis=-1).sum() > 20 and not (truth_only == EST_COLOUR).all(axis=-1).any()

    shifted = make_T(t=[0.03, 0.0, 0.0]) @ frame.T_cam_ee  # 3 cm to the camera's right
    drawn = draw_pose(frame.rgb, frame.mask, frame.K, mesh, shifted)
    ys, xs = np.nonzero((drawn == EST_COLOUR).all(axis=-1))
    expected = silhouette(mesh, frame.K, shifted, frame.mask.shape)
    assert len(xs) > 20 and abs(xs.mean() - np.nonzero(expected)[1].mean()) < 2.0
    assert xs.mean() > np.nonzero(frame.mask)[1].mean() + 3  # drawn right of the ground truth


def test_zoomed_view_keeps_the_pose_and_nothing_beyond_the_image(tiny_dataset):
    mesh, frame = next(_frames(tiny_dataset))
    rgb, mask, K = zoom(frame.rgb, frame.mask, frame.K, 240)
    projected = silhouette(mesh, K, frame.T_cam_ee, mask.shape)
    assert rgb.shape == (240, 240, 3) and (projected & mask).sum() / (projected | mask).sum() > 0.9

    corner = np.zeros_like(frame.mask)
    corner[:10, :10] = True  # the view spans x, y in -9.9..18.9: the part left of and above the image is empty
    _, zoomed, _ = zoom(frame.rgb, corner, frame.K, 100)
    assert zoomed.sum() > 800 and not zoomed[:30].any() and not zoomed[:, :30].any()


def _filled(mesh, K, T_cam_model, shape):
    """The overlays' silhouette before FEEPE's rasteriser drew it: each triangle filled by OpenCV at 4x and
    1/16 px, a pixel kept where half of it is covered."""
    cam = transform_points(T_cam_model, mesh.vertices)
    tri = project(cam, K, min_z=0.01)[mesh.faces[(cam[mesh.faces, 2] > 0.01).all(axis=1)]]
    fine = np.zeros((shape[0] * 4, shape[1] * 4), np.uint8)
    for triangle in np.round(((tri + 0.5) * 4 - 0.5) * 16).astype(np.int32):
        cv2.fillConvexPoly(fine, triangle, 255, cv2.LINE_8, 4)
    return cv2.resize(fine, (shape[1], shape[0]), interpolation=cv2.INTER_AREA) >= 128


def test_the_silhouette_is_the_former_fill_but_along_its_outline():
    """Pixel centres (the rasteriser, as the rendered masks) against half-covered pixels (the former fill):
    the same pixels but a few on the outline."""
    blob = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    blob.vertices *= np.random.default_rng(3).uniform(0.7, 1.3, (len(blob.vertices), 1))
    mesh = Mesh(blob.vertices, np.ascontiguousarray(blob.faces, dtype=np.int64), 0.052)
    K = np.array([[300.0, 0, 79.5], [0, 300.0, 59.5], [0, 0, 1]])
    for t in ([0.0, 0.0, 0.4], [0.013, -0.021, 0.3], [0.05, 0.02, 0.6]):
        T = make_T(Rotation.from_euler("xyz", t).as_matrix(), t)
        drawn, former = silhouette(mesh, K, T, (120, 160)), _filled(mesh, K, T, (120, 160))
        outline = cv2.dilate(former.astype(np.uint8), np.ones((3, 3))) > cv2.erode(former.astype(np.uint8),
                                                                                    np.ones((3, 3)))
        assert former.sum() > 500 and not (drawn ^ former)[~outline].any()
        assert (drawn ^ former).sum() < 0.1 * outline.sum()
