"""Arm motion: smooth random joint trajectories, and the checks that decide whether a segment is
usable (end-effector inside the image and visible enough, arm above the floor)."""

from __future__ import annotations

import numpy as np
import trimesh

from kernel.camera import project
from kernel.transforms import inv_T, transform_points
from syneepose.robots.model import read_urdf

IN_VIEW = 0.999  # a frame holds the end-effector in the image when this share of its surface points lies inside


def min_jerk(s: np.ndarray) -> np.ndarray:
    """0 -> 1 with zero velocity and acceleration at both ends (monotone, so limits hold)."""
    return 10 * s**3 - 15 * s**4 + 6 * s**5


def trajectory(rng, home, limits, n_frames: int, n_waypoints: int, spread: float) -> np.ndarray:
    """Waypoints around `home` (within `spread` rad and the limits) joined by min-jerk blends."""
    lo, hi = np.asarray(limits, float).T
    home = np.asarray(home, float)
    way = np.clip(home + rng.uniform(-spread, spread, (n_waypoints, len(home))), lo, hi)
    if n_frames == 1:
        return way[:1]
    t = np.linspace(0.0, n_waypoints - 1, n_frames)
    k = np.minimum(t.astype(int), n_waypoints - 2)
    blend = min_jerk(t - k)[:, None]
    return way[k] + blend * (way[k + 1] - way[k])


def in_image(p_cam: np.ndarray, K: np.ndarray, width: int, height: int, margin: float) -> np.ndarray:
    """Which camera points (..., 3) lie 5 cm or more in front of the camera and inside the image, `margin` (a
    share of its size) from its border."""
    uv = project(p_cam, K, min_z=1e-9)
    return (p_cam[..., 2] > 0.05) & (uv[..., 0] >= margin * width) & (uv[..., 0] <= (1 - margin) * width - 1) \
        & (uv[..., 1] >= margin * height) & (uv[..., 1] <= (1 - margin) * height - 1)


class MotionChecks:
    """Fast pre-render checks on convex link hulls: end-effector points projected into the image and
    ray-cast against the arm (a conservative occluder), floor clearance and self-collision."""

    def __init__(self, robot, ee_mesh: trimesh.Trimesh, n_points: int = 300):
        self.robot = robot
        self.points, _ = trimesh.sample.sample_surface(ee_mesh, n_points, seed=0)  # in ee_mount, metres
        arm = read_urdf(robot.urdf)
        ee_links = set(robot.ee_links)
        self.hulls = {}
        for link in arm.links:
            if link.name in ee_links or not link.visuals:
                continue
            meshes = [trimesh.load(str(robot.urdf.parent / v.mesh), force="mesh", process=False)
                      .apply_transform(v.origin) for v in link.visuals]
            self.hulls[link.name] = trimesh.util.concatenate(meshes).convex_hull
        self.hull_ee = ee_mesh.convex_hull
        self.moving: set[str] = set()
        changed = True
        while changed:
            before = len(self.moving)
            self.moving |= {j.child for j in arm.joints if j.type != "fixed" or j.parent in self.moving}
            changed = len(self.moving) != before
        self._collision = self._collision_manager(arm)

    def _collision_manager(self, arm):
        """Pairs that touch at the home pose or share a joint are allowed to touch (their hulls overlap)."""
        manager = trimesh.collision.CollisionManager()
        for name, hull in self.hulls.items():
            manager.add_object(name, hull)
        manager.add_object(self.robot.ee_root, self.hull_ee)
        self._bodies = [*self.hulls, self.robot.ee_root]
        attached = {}
        for j in arm.joints:
            attached.setdefault(j.child, j.parent)
        def body_of(link):
            while link not in self._bodies and link in attached:
                link = attached[link]
            return link
        self._allowed = {frozenset((body_of(j.parent), body_of(j.child))) for j in arm.joints}
        self._pose_bodies(manager, np.asarray(self.robot.arm.home)[None], 0)
        _, pairs = manager.in_collision_internal(return_names=True)
        self._allowed |= {frozenset(p) for p in pairs}
        return manager

    def _pose_bodies(self, manager, q, i):
        poses = self.robot.T_base_link(q)
        for name in self._bodies:
            manager.set_transform(name, poses[name][i])

    def self_collision(self, q: np.ndarray) -> np.ndarray:
        """Per frame: True where two link hulls that are apart at home intersect."""
        out = np.zeros(len(q), bool)
        for i in range(len(q)):
            self._pose_bodies(self._collision, q, i)
            _, pairs = self._collision.in_collision_internal(return_names=True)
            out[i] = any(frozenset(p) not in self._allowed for p in pairs)
        return out

    def check(self, q: np.ndarray, T_base_cam: np.ndarray, K: np.ndarray, width: int, height: int,
              margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Per frame: (fraction of points inside the image, fraction inside and unoccluded)."""
        return self.seen(q, T_base_cam, K, width, height, self.points, margin)

    def accepts(self, q: np.ndarray, T_base_cam: np.ndarray, K: np.ndarray, width: int, height: int, margin: float,
                min_visible: float, frames: np.ndarray) -> bool:
        """`check`'s verdict on the `frames` (a mask): IN_VIEW of the points inside the image and at least
        `min_visible` unoccluded. The same verdict, number for number, at a fraction of the cost: the image test
        of every frame before any ray is cast, and the casting stopped at the first frame that fails (planning
        rejects most cameras; `check` cast rays for all 16 frames of each, 0.3 s)."""
        poses = self.robot.T_base_link(q)
        T_cam_base = inv_T(T_base_cam)
        kept = np.flatnonzero(frames)
        if not all(self._inside(poses, T_cam_base, i, self.points, K, width, height, margin).mean() >= IN_VIEW
                   for i in kept):
            return False
        return all(self._seen_at(poses, T_cam_base, i, self.hulls, self.points, K, width, height, margin)[1]
                   >= min_visible for i in kept)

    def seen(self, q: np.ndarray, T_base_cam: np.ndarray, K: np.ndarray, width: int, height: int,
             points_ee: np.ndarray, margin: float = 0.0, ee_occludes: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Per frame: the fraction of `points_ee` (fixed to the end-effector) inside the image, and inside and
        unoccluded by the arm's hulls (and the end-effector's, for points beside it such as a marker board)."""
        poses = self.robot.T_base_link(q)
        T_cam_base = inv_T(T_base_cam)
        hulls = dict(self.hulls, **({self.robot.ee_root: self.hull_ee} if ee_occludes else {}))
        seen = np.array([self._seen_at(poses, T_cam_base, i, hulls, points_ee, K, width, height, margin)
                         for i in range(len(q))]).reshape(len(q), 2)
        return seen[:, 0], seen[:, 1]

    def _inside(self, poses, T_cam_base, i, points_ee, K, width, height, margin) -> np.ndarray:
        return in_image(self._points_cam(poses, T_cam_base, i, points_ee), K, width, height, margin)

    def _points_cam(self, poses, T_cam_base, i, points_ee) -> np.ndarray:
        return transform_points(T_cam_base @ poses[self.robot.ee_root][i], points_ee)

    def _seen_at(self, poses, T_cam_base, i, hulls, points_ee, K, width, height, margin) -> tuple[float, float]:
        """Frame i: (share of the points inside the image, share inside and not behind a hull)."""
        p_cam = self._points_cam(poses, T_cam_base, i, points_ee)
        ok = in_image(p_cam, K, width, height, margin)
        if not ok.any():
            return ok.mean(), 0.0
        occluders = trimesh.util.concatenate([h.copy().apply_transform(T_cam_base @ poses[name][i])
                                              for name, h in hulls.items()])
        targets = p_cam[ok]
        dist = np.linalg.norm(targets, axis=1)
        dirs = targets / dist[:, None]
        locs, ray_idx, _ = occluders.ray.intersects_location(np.zeros_like(dirs), dirs, multiple_hits=False)
        blocked = np.zeros(len(dirs), bool)
        hit = np.linalg.norm(locs, axis=1) < dist[ray_idx] - 0.005
        blocked[ray_idx[hit]] = True
        return ok.mean(), (~blocked).sum() / len(points_ee)

    def ee_points(self, q: np.ndarray) -> np.ndarray:
        """The end-effector's surface points (`points`) in the base, per frame: (frames, points, 3)."""
        T = self.robot.T_base_link(q)[self.robot.ee_root]
        return np.einsum("fij,pj->fpi", T[:, :3, :3], self.points) + T[:, None, :3, 3]

    def above_floor(self, q: np.ndarray, clearance: float) -> np.ndarray:
        """Every moving arm link origin stays clearance/2 above the floor (z = 0), the mount `clearance`."""
        poses = self.robot.T_base_link(q)
        z = np.stack([poses[name][:, 2, 3] for name in self.hulls if name in self.moving], 1)
        ee_z = poses[self.robot.ee_root][:, 2, 3]
        return (z.min(1) > clearance / 2) & (ee_z > clearance)
