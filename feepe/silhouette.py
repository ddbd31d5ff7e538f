"""Silhouette alignment (our extension, issue 13; not in the paper): the end-effector model's occluding
contour, projected under the shared camera-to-base pose, laid onto each key frame's observed mask - or,
given the robot's mask and link poses, the whole robot's outline (every arm link's mesh placed by forward
kinematics, as EasyHeC fits the whole arm's mask; here by contour distance, not differentiable rendering).

The mask is the one input no depth noise touches. Each key frame keeps the signed distance to its mask
boundary; the model's outer contour points (rim edges of the mesh whose image just outside misses the
model's projected triangles, feepe/raster.py) are pulled to distance zero. Contour points are exact mesh geometry,
not pixel centres of a rendered mask, so the fit carries no half-pixel shrink.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import cv2
import numba
import numpy as np
import trimesh

from feepe import raster
from feepe.depth import depth_at
from feepe.icp import Pairing, PlaneTerms, SurfaceModel, associate_again
from feepe.optimize import Term, add_row, cost_of_squares, jacobian_row, robust_sigma, store_sums, sums_of
from kernel.camera import project
from kernel.errors import UserError
from kernel.transforms import inv_T, transform_points

BORDER_PX = 2  # contour points this close to the image border are dropped: the mask is cut there
INSIDE_PX = 2.5  # a pixel this far (px) from any pixel off a rendered mask is inside the model's outline
_DISK = (np.add.outer(np.arange(-2, 3) ** 2, np.arange(-2, 3) ** 2) <= INSIDE_PX**2).astype(np.uint8)


OCCLUDER_MARGIN_M = 0.03  # observed depth this much nearer than the model there: something stands in front
NEAR_M = 0.05  # contour edges nearer the camera than this are left out (a link can reach behind it)
REUSE_PX = 1.0  # a frame's contour (and mask IoU) is extracted again once the model has moved this far in its image
# (before: 0.5 px). --masks none, AUC@1cm ADD / calibration after 15 frames, seeds 131, 157, 151, 137: -0.02, -0.01,
# +0.02, +0.02 / +0.001, +0.002, +0.009, -0.004 mm; data/mini exact depth and the masks handed in the same to 0.01;
# `ms` on seed 131 -4 % (three paired runs)
KEPT = 4  # the last extractions kept per frame: a descent's check revisits poses a few solves back
COARSE_M = 0.003  # mask IoUs (at every second pixel, where a pixel spans 5 mm or more) and the coarse stages
# of a descent use a copy of each mesh clustered to this grid: 2-6x fewer faces; at mini's distances its
# contour lies on the exact mask's outline as closely as the exact contour does (0.2 px mean)


@dataclass
class MaskView:
    """One frame's observed mask as a field: signed distance to its boundary (px, > 0 outside), and the
    frame's depth, which tells a visible mask cut by an occluder from the object's own outline."""
    field: np.ndarray  # (H, W, 3) float32: the signed distance and its d/du, d/dv, sampled together
    mask: np.ndarray  # (H, W) bool
    K: np.ndarray  # (3, 3) full-image intrinsics
    depth: np.ndarray | None = None  # (H, W) metres, 0 unknown; None: no occlusion reasoning
    # the last KEPT contours extracted on this frame per model and point spacing, newest first: (T_cam_parts,
    # visible model points per part) each. A new key frame moves the calibration a little; the other frames'
    # outlines then stay put.
    contours: dict = field(default_factory=dict, repr=False)
    ious: dict = field(default_factory=dict, repr=False)  # the same for the mask IoU per model and stride
    # the frame's depth points' last pairing with the model (`depth_planes`; it holds for any gate)
    pairing: Pairing | None = field(default=None, repr=False)

    @property
    def sdt(self) -> np.ndarray:
        return self.field[..., 0]

    def occluded(self, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Pixels off the visible mask whose observed depth is clearly nearer than `z` (a stereo hole,
        depth 0, is not evidence of anything)."""
        if self.depth is None:
            return np.zeros(len(uv), bool)
        seen = depth_at(self.depth, uv)
        return (seen > 0) & (seen < z - OCCLUDER_MARGIN_M) & ~(depth_at(self.mask.astype(float), uv) > 0)


def mask_view(mask: np.ndarray, K: np.ndarray, depth: np.ndarray | None = None) -> MaskView:
    """The zero level lies half-way between the last mask pixel centre and the first background one."""
    m = np.asarray(mask, bool).astype(np.uint8)
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    sdt = np.where(m > 0, 0.5 - inside, outside - 0.5).astype(np.float32)
    gu = cv2.Sobel(sdt, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
    gv = cv2.Sobel(sdt, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
    return MaskView(np.stack([sdt, gu, gv], -1), m > 0, np.asarray(K, float),
                    None if depth is None else np.asarray(depth, float))


@dataclass
class Outline:
    """The mask whose outline counts (one part's, or the union of the robot's parts) as the contour
    extraction asks it: which pixels lie deep inside its rendered mask (what is there is passed over),
    and its image triangles, which the rest is tested against exactly."""
    deep_interior: np.ndarray  # (H, W) bool: no pixel off the mask within INSIDE_PX
    interior: np.ndarray  # (H, W) bool: no pixel off the mask among the 8 neighbours
    triangles: np.ndarray  # (T, 3, 2) image triangles of every part

    @classmethod
    def of(cls, parts: list, T_cam_parts, K: np.ndarray, shape: tuple[int, int]) -> "Outline":
        """parts: SilhouetteModel each, placed at T_cam_parts."""
        tri = np.concatenate([raster.triangles(m.vertices, m.faces, T, K)[0] for m, T in zip(parts, T_cam_parts)])
        mask = raster.mask(tri, shape).astype(np.uint8)
        return cls(cv2.erode(mask, _DISK) > 0, cv2.erode(mask, np.ones((3, 3), np.uint8)) > 0, tri)


class SilhouetteModel:
    """The mesh's edges that can be on an occluding contour, and its faces for the rasteriser."""

    def __init__(self, mesh: trimesh.Trimesh, coarse_m: float | None = COARSE_M):
        # corners that differ only in normals or texture coordinates are one: else every edge of a crease
        # has one face, counts as a rim and is sampled and probed (most of the Franka hand's 24k edges)
        mesh = mesh.copy()
        mesh.merge_vertices(merge_tex=True, merge_norm=True)
        self.mesh = mesh
        self.vertices = np.ascontiguousarray(mesh.vertices, dtype=float)
        self.faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        # the same shape clustered to a coarse grid, for the refinement's mask IoUs and coarse stages
        self.coarse = self if coarse_m is None else SilhouetteModel(
            trimesh.Trimesh(*raster.clustered(self.vertices, self.faces, coarse_m), process=False), None)
        normals = mesh.face_normals
        pairs = mesh.face_adjacency
        # an edge with one face (open meshes) is always a candidate; outward is away from its face
        border = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)
        b_edges, b_face = mesh.edges_sorted[border], mesh.edges_face[border]
        mid = mesh.vertices[b_edges].mean(1)
        along = mesh.vertices[b_edges[:, 1]] - mesh.vertices[b_edges[:, 0]]
        away = mid - mesh.triangles_center[b_face]
        away -= along * (np.sum(away * along, 1) / np.maximum(np.sum(along * along, 1), 1e-18))[:, None]
        self.edges = np.concatenate([mesh.face_adjacency_edges, b_edges]).astype(int)
        # each edge's two faces' normals (an open edge: its face's and the reverse) and planes' offsets n . mid:
        # a face turns away from an eye with n . eye < offset, and a rim edge has one face each way
        self.normal_a = np.concatenate([normals[pairs[:, 0]], normals[b_face]])
        self.normal_b = np.concatenate([normals[pairs[:, 1]], -normals[b_face]])
        self.outward = np.concatenate([normals[pairs[:, 0]] + normals[pairs[:, 1]], away])
        mid = mesh.vertices[self.edges].mean(1)
        self.offset_a, self.offset_b = np.sum(self.normal_a * mid, 1), np.sum(self.normal_b * mid, 1)
        self.centre = mesh.bounds.mean(0)  # the bounding sphere's (motion and IoU bounds, position starts)
        self.radius = float(np.linalg.norm(mesh.vertices - self.centre, axis=1).max())

    @classmethod
    def from_ply(cls, path: Path, scale: float = 0.001) -> "SilhouetteModel":
        """BOP models are in mm (scale 0.001)."""
        path = Path(path)
        if not path.is_file():
            raise UserError(f"{path}: no such model; silhouette refinement needs the end-effector's BOP model")
        mesh = trimesh.load(path, force="mesh")
        mesh.apply_scale(scale)
        return cls(mesh)

    def contour(self, T_cam_ee: np.ndarray, K: np.ndarray, shape: tuple[int, int],
                step_px: float = 1.0) -> np.ndarray:
        """Model-frame points on the outer occluding contour of the model seen at `T_cam_ee`, about one
        per `step_px` of image length."""
        return PartsSilhouette([self]).contours(T_cam_ee[None], K, shape, step_px)[0]

    def candidates(self, T_cam_ee: np.ndarray, K: np.ndarray, shape: tuple[int, int], step_px: float,
                   outline: Outline, probe_px: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
        """Model-frame points on rim edges (one face seen, one not) near `outline`, about one per `step_px`
        of image length, and the image points `probe_px` outside them: a point is on the outline where its
        probe misses every triangle of the outline's mask. Points deep in the mask, within BORDER_PX of the
        image border or on an edge nearer the camera than NEAR_M are left out."""
        return _rim_samples(self.vertices, self.edges, self.normal_a, self.normal_b, self.offset_a, self.offset_b,
                            self.outward, np.ascontiguousarray(T_cam_ee, dtype=float), inv_T(T_cam_ee)[:3, 3].copy(),
                            np.ascontiguousarray(K, dtype=float), outline.deep_interior, outline.interior,
                            float(step_px), float(probe_px))

    def render(self, T_cam_ee: np.ndarray, K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """The model's mask at pixel centres (as a one-sample index pass)."""
        return self.render_depth(T_cam_ee, K, shape) > 0

    def render_depth(self, T_cam_ee: np.ndarray, K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """The model's depth (m along the optical axis, 0 off the model) at pixel centres."""
        return raster.render_depth(self.vertices, self.faces, T_cam_ee, K, shape)


class PartsSilhouette:
    """What a mask shows, as meshes: the end-effector alone, or the robot (the end-effector first, then the
    arm links). Frame data give each part's pose in the base frame, `T_base_parts` (n, 4, 4), from FK."""

    def __init__(self, parts: list[SilhouetteModel]):
        self.parts = list(parts)

    @cached_property
    def coarse(self) -> "PartsSilhouette":
        return PartsSilhouette([p.coarse for p in self.parts])

    def contours(self, T_cam_parts: np.ndarray, K: np.ndarray, shape: tuple[int, int],
                 step_px: float) -> list[np.ndarray]:
        """Each part's model-frame points on the outline of the union of all parts."""
        outline = Outline.of(self.parts, T_cam_parts, K, shape)
        found = [m.candidates(T, K, shape, step_px, outline) for m, T in zip(self.parts, T_cam_parts)]
        seen = ~raster.covered(outline.triangles, np.concatenate([probe for _, probe in found]), shape)
        ends = np.cumsum([len(P) for P, _ in found])
        return [P[seen[end - len(P):end]] for (P, _), end in zip(found, ends)]

    def render_parts(self, T_cam_parts: np.ndarray, K: np.ndarray,
                     shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """The nearest part's depth (m, 0 off the robot) and index (-1 off the robot) at each pixel centre; where
        two parts lie at the very same depth, the first of them. One z-buffer for all parts (drawing each into its
        own and taking the nearest over their stack cost twice as much, in the segmentation of every frame)."""
        z, part = np.zeros(shape), np.full(shape, -1, np.int64)
        for i, (m, T) in enumerate(zip(self.parts, T_cam_parts)):
            raster.draw_depth(z, m.vertices, m.faces, T, K, part, i)
        return z, part

    def render_depth(self, T_cam_parts: np.ndarray, K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """The nearest part's depth at each pixel centre (m, 0 off the robot)."""
        z = np.zeros(shape)
        for m, T in zip(self.parts, T_cam_parts):
            raster.draw_depth(z, m.vertices, m.faces, T, K)
        return z

    @cached_property
    def _spheres(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array([m.centre for m in self.parts], float), np.array([m.radius for m in self.parts], float)

    def sphere_boxes(self, T_cam_parts: np.ndarray, K: np.ndarray) -> np.ndarray | None:
        """Image boxes that hold each part's bounding sphere, (n, 4): first and last column, first and last row
        (px, not clipped to the image); None when a sphere reaches the near plane, whose image no box holds."""
        boxes = []
        for m, T in zip(self.parts, T_cam_parts):
            (x, y, z), r = T[:3, :3] @ m.centre + T[:3, 3], m.radius
            if z - r <= raster.NEAR_M:
                return None
            # over the cube around the sphere X/Z and Y/Z are extreme at its corners
            corners = np.array([(a, b, c) for a in (x - r, x + r) for b in (y - r, y + r) for c in (z - r, z + r)])
            uv = project(corners, K, min_z=raster.NEAR_M)
            boxes.append((uv[:, 0].min(), uv[:, 0].max(), uv[:, 1].min(), uv[:, 1].max()))
        return np.array(boxes)

    def span_px(self, T_cam_parts: np.ndarray, K: np.ndarray) -> float:
        """A bound on the parts' image extent (px): the larger side of the box around their `sphere_boxes`; inf
        when a sphere reaches the near plane."""
        boxes = self.sphere_boxes(T_cam_parts, K)
        if boxes is None:
            return np.inf
        return float(max(boxes[:, 1].max() - boxes[:, 0].min(), boxes[:, 3].max() - boxes[:, 2].min()))

    def motion_px(self, T_a: np.ndarray, T_b: np.ndarray, K: np.ndarray) -> float:
        """A bound on how far any model point moves in the image between two poses of the parts (T_a, T_b:
        (n, 4, 4); small motions): per part, its bounding sphere's centre shift plus its radius turned through
        the rotation, at the sphere's near side; the largest over the parts."""
        return _motion_px(np.ascontiguousarray(T_a, dtype=float), np.ascontiguousarray(T_b, dtype=float),
                          *self._spheres, float(max(K[0, 0], K[1, 1])))


@numba.njit(cache=True, nogil=True, parallel=True)
def _rim_samples(V, edges, normal_a, normal_b, offset_a, offset_b, outward, T, eye, K, deep_interior, interior,
                 step_px, probe_px):
    """SilhouetteModel.candidates over the edges on both cores: each edge's samples counted, then written
    at their offsets, so the output keeps the edges' order."""
    counts = np.zeros(edges.shape[0] + 1, np.int64)
    P_out, probe_out = np.empty((0, 3)), np.empty((0, 2))
    for e in numba.prange(edges.shape[0]):
        counts[e + 1] = _edge_samples(V, edges, normal_a, normal_b, offset_a, offset_b, outward, T, eye, K,
                                      deep_interior, interior, step_px, probe_px, e, P_out, probe_out, -1)
    starts = np.cumsum(counts)
    P_out, probe_out = np.empty((starts[-1], 3)), np.empty((starts[-1], 2))
    for e in numba.prange(edges.shape[0]):
        if counts[e + 1]:
            _edge_samples(V, edges, normal_a, normal_b, offset_a, offset_b, outward, T, eye, K, deep_interior,
                          interior, step_px, probe_px, e, P_out, probe_out, starts[e])
    return P_out, probe_out


@numba.njit(cache=True, nogil=True, inline="always")
def _edge_samples(V, edges, normal_a, normal_b, offset_a, offset_b, outward, T, eye, K, deep_interior, interior,
                  step_px, probe_px, e, P_out, probe_out, at):
    """Edge e's samples, in scalars (a small array per edge would cost more than the edge's arithmetic):
    their number, and with `at` >= 0 the samples and probes written from row `at`."""
    h, w = deep_interior.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    away_a = offset_a[e] > normal_a[e, 0] * eye[0] + normal_a[e, 1] * eye[1] + normal_a[e, 2] * eye[2]
    away_b = offset_b[e] > normal_b[e, 0] * eye[0] + normal_b[e, 1] * eye[1] + normal_b[e, 2] * eye[2]
    if away_a == away_b:
        return 0
    i, j = edges[e, 0], edges[e, 1]
    xa, ya, za = _to_camera(T, V[i, 0], V[i, 1], V[i, 2])
    xb, yb, zb = _to_camera(T, V[j, 0], V[j, 1], V[j, 2])
    if not (za > NEAR_M and zb > NEAR_M):
        return 0
    ua, va = raster.to_pixel(fx, fy, cx, cy, xa, ya, za)
    ub, vb = raster.to_pixel(fx, fy, cx, cy, xb, yb, zb)
    if not (_off(deep_interior, ua, va) or _off(deep_interior, ub, vb)
            or _off(deep_interior, 0.5 * (ua + ub), 0.5 * (va + vb))):
        return 0
    length = min(np.sqrt((ub - ua) ** 2 + (vb - va) ** 2), h + w)  # longer edges leave the image
    n = max(1, int(np.ceil(length / step_px)))
    norm = max(np.sqrt(outward[e, 0] ** 2 + outward[e, 1] ** 2 + outward[e, 2] ** 2), 1e-12)
    nx, ny, nz = 1e-3 * outward[e, 0] / norm, 1e-3 * outward[e, 1] / norm, 1e-3 * outward[e, 2] / norm
    tx, ty, tz = _to_camera(T, nx, ny, nz, 0.0)  # a 1 mm step along the normal, turned into the camera
    m = 0
    for q in range(n):
        f = (q + 0.5) / n
        px = V[i, 0] + f * (V[j, 0] - V[i, 0])
        py = V[i, 1] + f * (V[j, 1] - V[i, 1])
        pz = V[i, 2] + f * (V[j, 2] - V[i, 2])
        x, y, z = _to_camera(T, px, py, pz)
        if z <= 0.0:
            continue
        u, v = raster.to_pixel(fx, fy, cx, cy, x, y, z)
        if not (BORDER_PX <= u <= w - 1 - BORDER_PX and BORDER_PX <= v <= h - 1 - BORDER_PX):
            continue
        if not _off(interior, u, v):
            continue
        if at >= 0:  # the probe: the image direction away from the silhouette, the normal projected
            u_normal, v_normal = raster.to_pixel(fx, fy, cx, cy, x + tx, y + ty, z + tz)
            du, dv = u_normal - u, v_normal - v
            d = max(np.sqrt(du * du + dv * dv), 1e-12)
            P_out[at + m, 0], P_out[at + m, 1], P_out[at + m, 2] = px, py, pz
            probe_out[at + m, 0], probe_out[at + m, 1] = u + probe_px * du / d, v + probe_px * dv / d
        m += 1
    return m


@numba.njit(cache=True, nogil=True)
def _to_camera(T, x, y, z, w=1.0):
    """T @ (x, y, z, w)[:3] in scalars (w = 0 turns a direction)."""
    return (T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + w * T[0, 3],
            T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + w * T[1, 3],
            T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + w * T[2, 3])


@numba.njit(cache=True, nogil=True)
def _off(region, u, v):
    """Whether the pixel nearest to (u, v) lies off `region` (off the image: clamped)."""
    h, w = region.shape
    return not region[min(max(int(np.rint(v)), 0), h - 1), min(max(int(np.rint(u)), 0), w - 1)]


def placed(T_cam_base: np.ndarray, T_base_parts: np.ndarray) -> np.ndarray:
    """Each part's pose in the camera, (n, 4, 4)."""
    return np.einsum("ij,njk->nik", T_cam_base, T_base_parts)


class SilhouetteTerm(Term):
    """Residuals: each contour point's signed distance to its frame's mask boundary, over its frame's
    `sigma_px` (one scale, or one per frame).

    The points are fixed for a term (re-extracted between solves, as ICP re-associates); the distance
    field's gradient carries the pose's Jacobian.
    """

    def __init__(self, base_points: np.ndarray, view: np.ndarray, views: list[MaskView],
                 sigma_px: float | np.ndarray):
        order = np.argsort(view, kind="stable")  # each view's points in one slice
        self.base_points, self.view = base_points[order], view[order]
        self.sigma_px = np.broadcast_to(np.asarray(sigma_px, float), (len(views),)).copy()
        self.bounds = np.searchsorted(self.view, np.arange(len(views) + 1))
        # the frames with points, one compiled call each: a numba typed list of the fields, which let one call
        # evaluate every frame, was compiled again in each process (0.4 s; its methods are not cached), and a call
        # costs microseconds
        self._frames = [(f, views[f].field, np.ascontiguousarray(views[f].K, dtype=float))
                        for f in range(len(views)) if self.bounds[f] < self.bounds[f + 1]]

    def residuals(self, T_cam_base: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        e, J = np.empty((len(self.view), 1)), np.empty((len(self.view), 1, 6)) if jacobian else np.empty((0, 1, 6))
        T = np.ascontiguousarray(T_cam_base, dtype=float)
        for f, field, K in self._frames:
            _term_rows(self.base_points, self.bounds[f], self.bounds[f + 1], K, field, T, self.sigma_px[f], e, J)
        return e, (J if jacobian else None)

    def normal_equations(self, T_cam_base: np.ndarray, H: np.ndarray, g: np.ndarray) -> float:
        return self._pass(T_cam_base, H, g, True)

    def cost(self, T_cam_base: np.ndarray) -> float:
        return self._pass(T_cam_base, np.zeros((6, 6)), np.zeros(6), False)

    def _pass(self, T_cam_base: np.ndarray, H: np.ndarray, g: np.ndarray, linearise: bool) -> float:
        if not self._frames:
            return 0.0
        T, squares = np.ascontiguousarray(T_cam_base, dtype=float), np.empty(len(self.view))
        for f, field, K in self._frames:
            _term_pass(self.base_points, self.bounds[f], self.bounds[f + 1], K, field, T, self.sigma_px[f], H, g,
                       squares, linearise)
        return cost_of_squares(squares)

    def __len__(self) -> int:
        return len(self.view)


@numba.njit(cache=True, nogil=True)
def _term_rows(points, start, end, K, field, T, sigma, e, J):
    """SilhouetteTerm.residuals of one frame, its points rows start:end, and, when J has rows, their Jacobian
    (optimize.jacobian_row)."""
    for i in range(start, end):
        e[i, 0], qx, qy, qz, gx, gy, gz = _contour_row(points, K, T, field, sigma, i, J.shape[0] > 0)
        if J.shape[0]:
            jacobian_row(J, i, qx, qy, qz, gx, gy, gz)


@numba.njit(cache=True, nogil=True)
def _term_pass(points, start, end, K, field, T, sigma, H, g, squares, linearise):
    """SilhouetteTerm's squared rows of one frame (rows start:end) into `squares` and, when `linearise`, those
    rows added to the normal equations (optimize.add_row)."""
    s = sums_of(H, g)
    for i in range(start, end):
        e, qx, qy, qz, gx, gy, gz = _contour_row(points, K, T, field, sigma, i, linearise)
        squares[i] = e ** 2
        if linearise:
            s = add_row(s, e, qx, qy, qz, gx, gy, gz)
    store_sums(s, H, g)


@numba.njit(cache=True, nogil=True, inline="always")
def _contour_row(points, K, T, field, sigma, i, gradient):
    """Row i of SilhouetteTerm, a point of the frame of intrinsics K and mask field `field`: the signed distance
    at its projection over sigma; the rotated point and, with `gradient`, the field's image gradient through the
    projection's derivative (optimize.jacobian_row's q and g; else zeros)."""
    h, w = field.shape[0], field.shape[1]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    qx = T[0, 0] * points[i, 0] + T[0, 1] * points[i, 1] + T[0, 2] * points[i, 2]
    qy = T[1, 0] * points[i, 0] + T[1, 1] * points[i, 1] + T[1, 2] * points[i, 2]
    qz = T[2, 0] * points[i, 0] + T[2, 1] * points[i, 1] + T[2, 2] * points[i, 2]
    x, y, z = qx + T[0, 3], qy + T[1, 3], max(qz + T[2, 3], 1e-6)
    u, v = raster.to_pixel(fx, fy, cx, cy, x, y, z)
    u, v = min(max(u, 0.0), w - 1.001), min(max(v, 0.0), h - 1.001)
    u0, v0 = int(u), int(v)
    a, b = u - u0, v - v0
    e = _bilinear(field, u0, v0, a, b, 0) / sigma
    if not gradient:
        return e, qx, qy, qz, 0.0, 0.0, 0.0
    du, dv = _bilinear(field, u0, v0, a, b, 1), _bilinear(field, u0, v0, a, b, 2)
    return (e, qx, qy, qz, du * fx / z / sigma, dv * fy / z / sigma,
            -(du * fx * x + dv * fy * y) / (z * z) / sigma)


@numba.njit(cache=True, nogil=True, inline="always")
def _bilinear(field, u0, v0, a, b, channel):
    """A channel of the field between the four pixels from (u0, v0), at fractions (a, b). A scalar, not a
    small array per point: allocating one cost more than the sampling."""
    return ((1 - a) * (1 - b) * field[v0, u0, channel] + a * (1 - b) * field[v0, u0 + 1, channel]
            + (1 - a) * b * field[v0 + 1, u0, channel] + a * b * field[v0 + 1, u0 + 1, channel])


def contour_term(model: PartsSilhouette, T_cam_base: np.ndarray, frames: list[tuple[np.ndarray, MaskView]],
                 sigma_px: float, step_px: float = 1.0, measured: bool = False) -> SilhouetteTerm:
    """frames: (T_base_parts, MaskView) each; the contours are those at the current pose. `measured`: each
    frame's scale is at least its residuals' robust spread at this pose (`robust_sigma`), so a mask that a
    segmenter got a few pixels wrong pulls less, against depth and against the other frames' masks, than
    one it got right (a segmenter's error varies from image to image)."""
    points, view = [], []
    for i, (T_base_parts, mv) in enumerate(frames):
        for T_base_part, P in zip(T_base_parts, visible_contour(model, placed(T_cam_base, T_base_parts), mv, step_px)):
            points.append(transform_points(T_base_part, P))
            view.append(np.full(len(P), i))
    term = SilhouetteTerm(np.concatenate(points), np.concatenate(view), [mv for _, mv in frames], sigma_px)
    if measured and len(term.view):
        e = np.abs(term.residuals(T_cam_base, False)[0][:, 0]) * sigma_px
        spread = [robust_sigma(e[a:b]) if b > a else 0.0 for a, b in zip(term.bounds[:-1], term.bounds[1:])]
        term.sigma_px = np.maximum(sigma_px, spread)
    return term


def depth_planes(T_cam_base: np.ndarray, views: list[MaskView], clouds: list[tuple[np.ndarray, np.ndarray]],
                 surfaces: SurfaceModel | list[SurfaceModel], gate_m: float) -> PlaneTerms:
    """`feepe.icp.associate` of each view's frame (`clouds` and `surfaces` as it takes them, one per view), the
    nearest-point queries made again only where a pairing kept on the view may have changed (`associate_again`): a
    new key frame moves the calibration a little, and pairing the other frames' 12000 points each afresh was a
    fifth of a later frame's cost (issue 34)."""
    surfaces = surfaces if isinstance(surfaces, list) else [surfaces] * len(clouds)
    found = []
    for mv, cloud, surface in zip(views, clouds, surfaces):
        planes, mv.pairing = associate_again(T_cam_base, cloud, surface, gate_m, mv.pairing)
        found.append(planes)
    return PlaneTerms.joined(found)


def visible_contour(model: PartsSilhouette, T_cam_parts: np.ndarray, mv: MaskView,
                    step_px: float) -> list[np.ndarray]:
    """Each part's model-frame contour points in one frame that nothing in front hides."""
    def extract() -> list[np.ndarray]:
        out = []
        for T_cam_part, P in zip(T_cam_parts, model.contours(T_cam_parts, mv.K, mv.sdt.shape, step_px)):
            Pc = transform_points(T_cam_part, P)
            hidden = mv.occluded(project(Pc, mv.K, min_z=1e-9), Pc[:, 2])  # by what stands in front: no evidence
            out.append(P[~hidden])
        return out

    return _reused(mv.contours, (model, step_px), model, T_cam_parts, mv.K, extract)


def _reused(store: dict, key, model: PartsSilhouette, T_cam_parts: np.ndarray, K: np.ndarray, compute):
    """The value stored under `key` at the nearest of a frame's last KEPT poses, computed again only when
    the model lies more than REUSE_PX (in the image) from each (a new key frame moves the calibration a
    little, and the other frames' stand; `Estimator._descend` revisits poses a few solves back)."""
    kept = store.setdefault(key, [])
    if kept:
        motion, i = min((model.motion_px(T, T_cam_parts, K), i) for i, (T, _) in enumerate(kept))
        if motion <= REUSE_PX:
            return kept[i][1]
    kept.insert(0, (T_cam_parts.copy(), compute()))
    del kept[KEPT:]
    return kept[0][1]


@numba.njit(cache=True, nogil=True)
def _motion_px(T_a, T_b, centres, radii, f):
    """PartsSilhouette.motion_px's bound for each part (T_a, T_b: (n, 4, 4)); the largest."""
    out = 0.0
    for n in range(T_a.shape[0]):
        c, r = centres[n], radii[n]
        shift, trace = 0.0, 0.0
        for i in range(3):
            a = T_a[n, i, 0] * c[0] + T_a[n, i, 1] * c[1] + T_a[n, i, 2] * c[2] + T_a[n, i, 3]
            b = T_b[n, i, 0] * c[0] + T_b[n, i, 1] * c[1] + T_b[n, i, 2] * c[2] + T_b[n, i, 3]
            shift += (b - a) ** 2
            if i == 2:
                near = max(min(a, b) - r, 1e-3)
            for j in range(3):
                trace += T_a[n, j, i] * T_b[n, j, i]
        angle = np.arccos(min(max((trace - 1.0) / 2.0, -1.0), 1.0))
        out = max(out, f * (np.sqrt(shift) + angle * r) / near)
    return out


def contour_fit(model: PartsSilhouette, T_cam_base: np.ndarray, frames: list[tuple[np.ndarray, MaskView]],
                cap_px: float = 3.0) -> tuple[float, float]:
    """Mean distance (px) of the contour points from their masks' boundaries (capped against outliers),
    and its standard error with frames, not points, as the independent samples: a segmenter's error runs
    smoothly along an outline, so one frame's points share it."""
    e, _ = contour_term(model, T_cam_base, frames, 1.0).residuals(T_cam_base, False)
    d = np.minimum(np.abs(e[:, 0]), cap_px)
    return (float(d.mean()), float(d.std() / np.sqrt(len(frames)))) if len(d) > 1 else (0.0, np.inf)


def mean_iou(model: PartsSilhouette, T_cam_base: np.ndarray, frames: list[tuple[np.ndarray, MaskView]],
             stride: int = 1) -> float:
    """How well a calibration explains every frame's mask: the mean mask IoU, on every `stride`-th pixel
    of each row and column (stride 2 ranks poses as well at a quarter of the pixels)."""
    return float(np.mean([frame_iou(model, placed(T_cam_base, T_base_parts), mv, stride)
                          for T_base_parts, mv in frames]))


def frame_iou(model: PartsSilhouette, T_cam_parts: np.ndarray, mv: MaskView, stride: int) -> float:
    """One frame's mask IoU on every `stride`-th pixel, stored like its contour (`_reused`)."""
    def measure() -> float:
        seen, K = strided(mv.mask, mv.K, stride)
        z_model = (model.coarse if stride > 1 else model).render_depth(T_cam_parts, K, seen.shape)
        drawn = z_model > 0
        if mv.depth is not None:  # model pixels that something nearer covers cannot be judged
            depth = mv.depth[::stride, ::stride]
            drawn &= ~((depth > 0) & (depth < z_model - OCCLUDER_MARGIN_M) & ~seen)
        return iou(drawn, seen)

    return _reused(mv.ious, (model, stride), model, T_cam_parts, mv.K, measure)


def iou_bound(model: PartsSilhouette, T_cam_parts: np.ndarray, mv: MaskView, stride: int) -> float:
    """An upper bound of frame_iou without rendering (for a decision that only asks whether an IoU can
    exceed a bar): the share of the mask inside the image boxes that hold each part's bounding sphere.
    What is drawn lies in the boxes, and the union of drawn and mask holds the mask."""
    seen, K = strided(mv.mask, mv.K, stride)
    total = np.count_nonzero(seen)
    if not total:
        return 1.0
    found = model.sphere_boxes(T_cam_parts, K)
    if found is None:
        return 1.0
    h, w = seen.shape
    boxes = np.zeros(seen.shape, bool)
    for u_min, u_max, v_min, v_max in found:
        u0, u1 = max(int(np.floor(u_min)), 0), min(int(np.ceil(u_max)), w - 1)
        v0, v1 = max(int(np.floor(v_min)), 0), min(int(np.ceil(v_max)), h - 1)
        boxes[v0:v1 + 1, u0:u1 + 1] = True  # an empty slice when the box misses the image
    return np.count_nonzero(seen & boxes) / total


def strided(image: np.ndarray, K: np.ndarray, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """The image on every `stride`-th pixel and the intrinsics of that grid."""
    return image[::stride, ::stride], np.diag([1.0 / stride, 1.0 / stride, 1.0]) @ K


def outline_pixels(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: the mask's pixels with a neighbour (of eight) off it; the image's border is no outline."""
    m = np.asarray(mask, np.uint8)
    return (m & ~(cv2.erode(m, np.ones((3, 3), np.uint8)) > 0)).astype(bool)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / union if union else 0.0
