"""Silhouette alignment (our extension, issue 13; not in the paper): the end-effector model's occluding
contour, projected under the shared camera-to-base pose, laid onto each key frame's observed mask - or,
given the robot's mask and link poses, the whole robot's outline (every arm link's mesh placed by forward
kinematics, as EasyHeC fits the whole arm's mask; here by contour distance, not differentiable rendering).

The mask is the one input no depth noise touches. Each key frame keeps the signed distance to its mask
boundary; the model's outer contour points (rim edges of the mesh whose outside neighbour pixel misses
the model, found by ray casting) are pulled to distance zero. Contour points are exact mesh geometry,
not pixel centres of a rendered mask, so the fit carries no half-pixel shrink.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from feepe.depth import backproject, depth_at
from feepe.optimize import project, row_jacobian
from kernel.errors import UserError
from kernel.transforms import inv_T, transform_points

BORDER_PX = 2  # contour points this close to the image border are dropped: the mask is cut there


OCCLUDER_MARGIN_M = 0.03  # observed depth this much nearer than the model there: something stands in front
NEAR_M = 0.05  # contour edges nearer the camera than this are left out (a link can reach behind it)
REUSE_PX = 0.5  # a frame's contour is extracted again once the model has moved this far in its image


@dataclass
class MaskView:
    """One frame's observed mask as a field: signed distance to its boundary (px, > 0 outside), and the
    frame's depth, which tells a visible mask cut by an occluder from the object's own outline."""
    field: np.ndarray  # (H, W, 3) float32: the signed distance and its d/du, d/dv, sampled together
    mask: np.ndarray  # (H, W) bool
    K: np.ndarray  # (3, 3) full-image intrinsics
    depth: np.ndarray | None = None  # (H, W) metres, 0 unknown; None: no occlusion reasoning
    # the last contour extracted on this frame per point spacing: (T_cam_parts, visible model points per
    # part). A new key frame moves the calibration a little; the other frames' outlines then stay put.
    contours: dict = field(default_factory=dict, repr=False)

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


def sample(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an (H, W) or (H, W, C) image at sub-pixel (u, v); uv inside the image."""
    h, w = img.shape[:2]
    u = np.clip(uv[:, 0], 0, w - 1.001)
    v = np.clip(uv[:, 1], 0, h - 1.001)
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    a, b = u - u0, v - v0
    if img.ndim == 3:
        a, b = a[:, None], b[:, None]
    return ((1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u0 + 1]
            + (1 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])


class SilhouetteModel:
    """The mesh's edges that can be on an occluding contour, and a ray caster for what is in front."""

    def __init__(self, mesh: trimesh.Trimesh):
        self.mesh = mesh
        self.rays = RayMeshIntersector(mesh)
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
        self.n1 = np.concatenate([normals[pairs[:, 0]], normals[b_face]])
        self.n2 = np.concatenate([normals[pairs[:, 1]], -normals[b_face]])
        self.outward = np.concatenate([normals[pairs[:, 0]] + normals[pairs[:, 1]], away])
        mid = mesh.vertices[self.edges].mean(1)
        self.o1, self.o2 = np.sum(self.n1 * mid, 1), np.sum(self.n2 * mid, 1)  # n . mid, for the rim test
        self.radius = float(np.linalg.norm(mesh.vertices - mesh.bounds.mean(0), axis=1).max())

    @classmethod
    def from_ply(cls, path: Path, scale: float = 0.001) -> "SilhouetteModel":
        """BOP models are in mm (scale 0.001)."""
        path = Path(path)
        if not path.is_file():
            raise UserError(f"{path}: no such model; silhouette refinement needs the end-effector's BOP model")
        mesh = trimesh.load(path, force="mesh")  # processed: vertices merged, so edges know both faces
        mesh.apply_scale(scale)
        return cls(mesh)

    def contour(self, T_cam_ee: np.ndarray, K: np.ndarray, shape: tuple[int, int],
                step_px: float = 1.0, probe_px: float = 0.3, others: list | None = None) -> np.ndarray:
        """Model-frame points on the outer occluding contour of the model seen at `T_cam_ee`, about one
        per `step_px` of image length. `others`: (SilhouetteModel, T_cam_model) of the robot's other parts;
        a point counts only where the pixel just outside it misses them too (the union's outline)."""
        T_ee_cam = inv_T(T_cam_ee)
        eye = T_ee_cam[:3, 3]
        rim = np.flatnonzero((self.o1 > self.n1 @ eye) != (self.o2 > self.n2 @ eye))  # one face seen, one not
        V = self.mesh.vertices
        a, b = V[self.edges[rim, 0]], V[self.edges[rim, 1]]
        ca, cb = transform_points(T_cam_ee, a), transform_points(T_cam_ee, b)
        front = (ca[:, 2] > NEAR_M) & (cb[:, 2] > NEAR_M)  # an arm link may reach behind the camera
        rim, a, b = rim[front], a[front], b[front]
        ua, ub = _project(ca[front], K), _project(cb[front], K)
        # most rims lie inside the silhouette: keep edges that come near the rendered mask's boundary
        near = cv2.distanceTransform(self.render(T_cam_ee, K, shape).astype(np.uint8), cv2.DIST_L2, 3) <= 2.5
        near = np.pad(near, 1, constant_values=True)
        keep = np.zeros(len(rim), bool)
        for uv in (ua, ub, 0.5 * (ua + ub)):
            iu = np.clip(np.round(uv[:, 0]).astype(int) + 1, 0, near.shape[1] - 1)
            iv = np.clip(np.round(uv[:, 1]).astype(int) + 1, 0, near.shape[0] - 1)
            keep |= near[iv, iu]
        a, b, ua, ub, normal = a[keep], b[keep], ua[keep], ub[keep], self.outward[rim[keep]]
        if len(a) == 0:
            return np.zeros((0, 3))
        length = np.minimum(np.linalg.norm(ub - ua, axis=1), sum(shape))  # longer edges leave the image
        n = np.maximum(1, np.ceil(length / step_px)).astype(int)
        edge = np.repeat(np.arange(len(a)), n)
        t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / np.repeat(n, n)
        P = a[edge] + t[:, None] * (b[edge] - a[edge])
        # the image direction away from the silhouette: the rim's surface normal, projected
        Pc = transform_points(T_cam_ee, P)
        u = _project(Pc, K)
        nrm = normal[edge] / np.maximum(np.linalg.norm(normal[edge], axis=1, keepdims=True), 1e-12)
        step = _project(Pc + 1e-3 * (nrm @ T_cam_ee[:3, :3].T), K) - u
        step /= np.maximum(np.linalg.norm(step, axis=1, keepdims=True), 1e-12)
        h, w = shape
        probe = u + probe_px * step
        inside = ((u[:, 0] >= BORDER_PX) & (u[:, 0] <= w - 1 - BORDER_PX)
                  & (u[:, 1] >= BORDER_PX) & (u[:, 1] <= h - 1 - BORDER_PX) & (Pc[:, 2] > 0))
        P, probe = P[inside], probe[inside]
        rays = backproject(probe, np.ones(len(probe)), K) @ T_ee_cam[:3, :3].T
        hit = self.rays.intersects_any(np.broadcast_to(eye, rays.shape).copy(), rays)
        P, rays = P[~hit], rays[~hit]
        for other, T_cam_other in others or ():
            if not len(P):
                break
            T_other_ee = inv_T(T_cam_other) @ T_cam_ee
            o_eye, o_rays = transform_points(T_other_ee, eye[None])[0], rays @ T_other_ee[:3, :3].T
            covered = other.rays.intersects_any(np.broadcast_to(o_eye, o_rays.shape).copy(), o_rays)
            P, rays = P[~covered], rays[~covered]
        return P

    def render(self, T_cam_ee: np.ndarray, K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """The model's mask at pixel centres (as a one-sample index pass), by ray casting."""
        mask = np.zeros(shape, bool)
        cast = self._pixel_rays(T_cam_ee, K, shape)
        if cast is not None:
            eye, rays, box = cast
            mask[box] = self.rays.intersects_any(np.broadcast_to(eye, rays.shape).copy(), rays).reshape(mask[box].shape)
        return mask

    def render_depth(self, T_cam_ee: np.ndarray, K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """The model's depth (m along the optical axis, 0 off the model) at pixel centres, by ray casting."""
        out = np.zeros(shape)
        cast = self._pixel_rays(T_cam_ee, K, shape)
        if cast is None:
            return out
        eye, rays, box = cast
        tri = self.rays.intersects_first(np.broadcast_to(eye, rays.shape).copy(), rays)
        hit = tri >= 0
        # eye + z * ray (the ray's optical-axis component is 1) meets the hit triangle's plane at depth z
        n, corner = self.mesh.face_normals[tri[hit]], self.mesh.triangles[tri[hit], 0]
        z = np.zeros(len(rays))
        z[hit] = np.sum(n * (corner - eye), 1) / np.sum(n * rays[hit], 1)
        out[box] = z.reshape(out[box].shape)
        return out

    def _pixel_rays(self, T_cam_ee: np.ndarray, K: np.ndarray, shape: tuple[int, int]):
        """Model-frame eye and rays through the pixel centres the bounding sphere may cover, and that box."""
        h, w = shape
        centre = T_cam_ee[:3, 3] + T_cam_ee[:3, :3] @ self.mesh.bounds.mean(0)
        if centre[2] <= self.radius:
            return None
        c = _project(centre[None], K)[0]
        r = self.radius * max(K[0, 0], K[1, 1]) / np.sqrt(centre[2] ** 2 - self.radius ** 2) + 1
        u0, u1 = max(0, int(c[0] - r)), min(w, int(np.ceil(c[0] + r)) + 1)
        v0, v1 = max(0, int(c[1] - r)), min(h, int(np.ceil(c[1] + r)) + 1)
        if u0 >= u1 or v0 >= v1:
            return None
        uu, vv = np.meshgrid(np.arange(u0, u1, dtype=float), np.arange(v0, v1, dtype=float))
        T_ee_cam = inv_T(T_cam_ee)
        rays = backproject(np.stack([uu.ravel(), vv.ravel()], 1), np.ones(uu.size), K) @ T_ee_cam[:3, :3].T
        return T_ee_cam[:3, 3], rays, np.s_[v0:v1, u0:u1]


class PartsSilhouette:
    """What a mask shows, as meshes: the end-effector alone, or the robot (the end-effector first, then the
    arm links). Frame data give each part's pose in the base frame, `T_base_parts` (n, 4, 4), from FK."""

    def __init__(self, parts: list[SilhouetteModel]):
        self.parts = list(parts)

    def contours(self, T_cam_parts: np.ndarray, K: np.ndarray, shape: tuple[int, int],
                 step_px: float) -> list[np.ndarray]:
        """Each part's model-frame points on the outline of the union of all parts."""
        placed = list(zip(self.parts, T_cam_parts))
        return [m.contour(T, K, shape, step_px, others=[o for j, o in enumerate(placed) if j != i])
                for i, (m, T) in enumerate(placed)]

    def render_depth(self, T_cam_parts: np.ndarray, K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """The nearest part's depth at each pixel centre (m, 0 off the robot)."""
        z = np.zeros(shape)
        for m, T in zip(self.parts, T_cam_parts):
            zi = m.render_depth(T, K, shape)
            z = np.where((zi > 0) & ((z == 0) | (zi < z)), zi, z)
        return z

    def motion_px(self, T_a: np.ndarray, T_b: np.ndarray, K: np.ndarray) -> float:
        return max(image_motion_px(m, a, b, K) for m, a, b in zip(self.parts, T_a, T_b))


def placed(T_cam_base: np.ndarray, T_base_parts: np.ndarray) -> np.ndarray:
    """Each part's pose in the camera, (n, 4, 4)."""
    return np.einsum("ij,njk->nik", T_cam_base, T_base_parts)


class SilhouetteTerm:
    """Residuals: each contour point's signed distance to its frame's mask boundary, over `sigma_px`.

    The points are fixed for a term (re-extracted between solves, as ICP re-associates); the distance
    field's gradient carries the pose's Jacobian.
    """

    def __init__(self, base_points: np.ndarray, view: np.ndarray, views: list[MaskView], sigma_px: float):
        order = np.argsort(view, kind="stable")  # each view's points in one slice
        self.base_points, self.view, self.views, self.sigma_px = base_points[order], view[order], views, sigma_px
        self.K = np.array([[v.K[0, 0], v.K[1, 1], v.K[0, 2], v.K[1, 2]] for v in views])[self.view]
        self.bounds = np.searchsorted(self.view, np.arange(len(views) + 1))

    def residuals(self, T_cam_base: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        Q = self.base_points @ T_cam_base[:3, :3].T
        uv, dpi = project(Q + T_cam_base[:3, 3], self.K)
        f = np.zeros((len(uv), 3))  # distance, d/du, d/dv
        for v, a, b in zip(self.views, self.bounds[:-1], self.bounds[1:]):
            if jacobian:
                f[a:b] = sample(v.field, uv[a:b])
            else:
                f[a:b, 0] = sample(v.sdt, uv[a:b])
        e = f[:, :1] / self.sigma_px
        if not jacobian:
            return e, None
        return e, row_jacobian(Q, np.einsum("ni,nij->nj", f[:, 1:], dpi) / self.sigma_px)


def contour_term(model: PartsSilhouette, T_cam_base: np.ndarray, frames: list[tuple[np.ndarray, MaskView]],
                 sigma_px: float, step_px: float = 1.0, measured: bool = False) -> SilhouetteTerm:
    """frames: (T_base_parts, MaskView) each; the contours are those at the current pose. `measured`: the
    scale is at least the residuals' robust spread at this pose (1.4826 x median), so masks that a
    segmenter got a few pixels wrong pull less against depth than exact ones."""
    points, view = [], []
    for i, (T_base_parts, mv) in enumerate(frames):
        for T_base_part, P in zip(T_base_parts, visible_contour(model, placed(T_cam_base, T_base_parts), mv, step_px)):
            points.append(transform_points(T_base_part, P))
            view.append(np.full(len(P), i))
    term = SilhouetteTerm(np.concatenate(points), np.concatenate(view), [mv for _, mv in frames], sigma_px)
    if measured and len(term.view):
        spread = 1.4826 * float(np.median(np.abs(term.residuals(T_cam_base, False)[0]))) * sigma_px
        term.sigma_px = max(sigma_px, spread)
    return term


def visible_contour(model: PartsSilhouette, T_cam_parts: np.ndarray, mv: MaskView,
                    step_px: float) -> list[np.ndarray]:
    """Each part's model-frame contour points in one frame that nothing in front hides, extracted again only
    when a part has moved more than REUSE_PX in the image since the frame's last extraction."""
    last = mv.contours.get(step_px)
    if last is not None and model.motion_px(last[0], T_cam_parts, mv.K) <= REUSE_PX:
        return last[1]
    out = []
    for T_cam_part, P in zip(T_cam_parts, model.contours(T_cam_parts, mv.K, mv.sdt.shape, step_px)):
        Pc = transform_points(T_cam_part, P)
        out.append(P[~mv.occluded(_project(Pc, mv.K), Pc[:, 2])])  # hidden by what stands in front: no evidence
    mv.contours[step_px] = (T_cam_parts.copy(), out)
    return out


def image_motion_px(model: SilhouetteModel, T_a: np.ndarray, T_b: np.ndarray, K: np.ndarray) -> float:
    """A bound on how far any model point moves in the image between two poses (small motions): the
    bounding sphere's centre shift plus its radius turned through the rotation, at the sphere's near side."""
    c = model.mesh.bounds.mean(0)
    a, b = T_a[:3, :3] @ c + T_a[:3, 3], T_b[:3, :3] @ c + T_b[:3, 3]
    cos = np.clip((np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1) / 2, -1.0, 1.0)
    near = max(min(a[2], b[2]) - model.radius, 1e-3)
    return float(max(K[0, 0], K[1, 1]) * (np.linalg.norm(b - a) + np.arccos(cos) * model.radius) / near)


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
    of each row and column (stride 2 ranks poses as well at a quarter of the rays)."""
    scale = np.diag([1.0 / stride, 1.0 / stride, 1.0])
    ious = []
    for T_base_parts, mv in frames:
        seen = mv.mask[::stride, ::stride]
        z_model = model.render_depth(placed(T_cam_base, T_base_parts), scale @ mv.K, seen.shape)
        if mv.depth is None:
            ious.append(iou(z_model > 0, seen))
            continue
        depth = mv.depth[::stride, ::stride]  # model pixels that something nearer covers cannot be judged
        hidden = (depth > 0) & (depth < z_model - OCCLUDER_MARGIN_M) & ~seen
        ious.append(iou((z_model > 0) & ~hidden, seen))
    return float(np.mean(ious))


def _project(P: np.ndarray, K: np.ndarray) -> np.ndarray:
    z = np.maximum(P[:, 2], 1e-9)
    return np.stack([K[0, 0] * P[:, 0] / z + K[0, 2], K[1, 1] * P[:, 1] / z + K[1, 2]], 1)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / union if union else 0.0
