"""Hard cases for mask-free estimation (issue 34), drawn only when the preset's `hard:` section asks: an object
crossing the line of sight to the end-effector, the end-effector leaving the image for a run of frames, and
link-like objects painted as the arm is. All pure numpy on the planned segment; each draws after everything
the segment drew before, so a preset without `hard:` plans the same segments as before."""

from __future__ import annotations

import numpy as np
import trimesh

from kernel.transforms import axis_angle_to_R, inv_T, make_T, transform_points
from syneepose.colour import srgb_to_linear
from syneepose.preset import ArmColoured, Exit, Occluder as OccluderSettings, Preset
from syneepose.scene.motion import IN_VIEW, in_image
from syneepose.scene.sample import MAX_PLACEMENTS, random_surface, uniform
from syneepose.scene.spec import Distractor, Occluder, SegmentSpec, Surface

TRANSITION = 2  # frames beside an exit run where the end-effector may be partly in view
PAN_STEPS_DEG = np.arange(0.0, 45.0, 1.5)  # camera turns tried to take the exit run out of view
OCCLUDER_KINDS = ("cube", "sphere", "cylinder")
CLEARANCE_M = 0.02  # the occluder's surface stays this far in front of the end-effector's bounding sphere


def exit_runs(rng, n_frames: int, settings: Exit) -> list[np.ndarray]:
    """Which frames the end-effector may be out of view: one run of a drawn length, at the start, the middle
    or the end (in a drawn order)."""
    k = int(np.clip(round(uniform(rng, settings.frames) * n_frames), 1, max(n_frames - 2 * TRANSITION - 1, 1)))
    runs = []
    for start in rng.permutation([0, (n_frames - k) // 2, n_frames - k]):
        out = np.zeros(n_frames, bool)
        out[start:start + k] = True
        runs.append(out)
    return runs


def free_frames(out: np.ndarray) -> np.ndarray:
    """Frames within TRANSITION of an exit run: the end-effector may be partly in view there."""
    near = np.zeros_like(out)
    for i in np.flatnonzero(out):
        near[max(i - TRANSITION, 0):i + TRANSITION + 1] = True
    return near & ~out


def turned_away(spec: SegmentSpec, points_base: np.ndarray, out: np.ndarray, width: int, height: int,
                margin: float) -> np.ndarray | None:
    """T_base_cam turned about its centre, away from the exit run, by the smallest angle that takes every
    end-effector point of the run out of view and keeps the other frames (but the transitions) whole in view;
    None if no turn does."""
    keep = ~out & ~free_frames(out)
    p_cam = transform_points(inv_T(spec.T_base_cam), points_base[out].reshape(-1, 3))
    away = -p_cam[:, :2].mean(0) / max(p_cam[:, 2].mean(), 1e-6)
    if np.linalg.norm(away) < 1e-9:
        return None
    axis = np.cross([0.0, 0.0, 1.0], [*away / np.linalg.norm(away), 0.0])
    for R in axis_angle_to_R(axis, np.deg2rad(PAN_STEPS_DEG)):
        T = spec.T_base_cam @ make_T(R)
        p_cam = transform_points(inv_T(T), points_base.reshape(-1, 3)).reshape(points_base.shape)
        inside = in_image(p_cam, spec.K, width, height, margin).mean(-1)
        if np.all(inside[keep] >= IN_VIEW) and np.all(inside[out] == 0.0):
            return T
    return None


def occluder(rng, settings: OccluderSettings, preset: Preset, spec: SegmentSpec, ee_path: np.ndarray,
             ee_radius: float, in_view: np.ndarray) -> Occluder:
    """An object passing in front of the end-effector (a hand or a tool carried past): it keeps a drawn share
    of the way from the camera along the line of sight to the end-effector and slides sideways across that
    line (level with the floor), crossing it at a frame drawn among those in view, at a speed that keeps it
    in front of the end-effector for about the drawn share of the frames."""
    n = len(ee_path)
    crossing = int(rng.choice(np.flatnonzero(in_view)))
    eye = spec.T_base_cam[:3, 3]
    between = uniform(rng, settings.between)
    side = np.cross(ee_path[crossing] - eye, [0.0, 0.0, 1.0])
    side *= rng.choice([-1.0, 1.0]) / max(np.linalg.norm(side), 1e-9)
    size = uniform(rng, settings.size)
    reach = np.linalg.norm(ee_path - eye, axis=1).min()
    between = min(between, 1.0 - (size / 2 + ee_radius + CLEARANCE_M) / reach)  # never inside the end-effector
    covered = max(uniform(rng, settings.frames) * n, 1.0)
    step = (size + 2 * ee_radius * between) / covered
    kind = str(rng.choice(OCCLUDER_KINDS))
    poses = np.stack([make_T(t=eye + between * (ee_path[i] - eye) + (i - crossing) * step * side) for i in range(n)])
    return Occluder(kind, size, poses, random_surface(rng, preset))


def arm_colours(robot) -> tuple[np.ndarray, np.ndarray]:
    """The arm's colours (linear RGB, (n, 3)) and the share of its surface each covers (its URDF visuals, by
    mesh area)."""
    ee = set(robot.ee_links)
    area: dict[tuple, float] = {}
    for link in robot.model.links:
        if link.name in ee:
            continue
        for visual in link.visuals:
            mesh = trimesh.load(str(robot.urdf.parent / visual.mesh), force="mesh", process=False)
            key = tuple(float(c) for c in visual.rgba[:3])
            area[key] = area.get(key, 0.0) + float(mesh.area)
    colours = srgb_to_linear(np.array(list(area)))
    shares = np.array(list(area.values()))
    return colours, shares / shares.sum()


def arm_coloured(rng, settings: ArmColoured, spec: SegmentSpec, avoid: np.ndarray,
                 colours: tuple[np.ndarray, np.ndarray], width: int, height: int) -> tuple[list[Distractor], int]:
    """Capsules as long and thick as arm links, each one of the arm's colours (`arm_colours`, drawn by the
    share of the arm it covers), on the floor where the camera sees it behind
    the robot: a pixel drawn in the image, its ray met with the floor farther than the end-effector's path,
    at least 0.3 m from the base and the path (xy) and 1.4 m from the base at most (inside the nearest wall).
    Returns the objects and how many found no place in MAX_PLACEMENTS draws."""
    K_inv = np.linalg.inv(spec.K)
    eye = spec.T_base_cam[:3, 3]
    reach = np.linalg.norm(avoid - eye, axis=1).max()
    out, dropped = [], 0
    for _ in range(int(rng.integers(*settings.count, endpoint=True))):
        length, radius = uniform(rng, settings.length), uniform(rng, settings.radius)
        colour = tuple(float(c) for c in colours[0][rng.choice(len(colours[1]), p=colours[1])])
        standing = bool(rng.random() < 0.5)
        yaw = rng.uniform(0.0, 2 * np.pi)
        for _attempt in range(MAX_PLACEMENTS):
            uv = rng.uniform([0.1 * width, 0.1 * height], [0.9 * width, 0.9 * height])
            ray = spec.T_base_cam[:3, :3] @ K_inv @ [uv[0], uv[1], 1.0]
            if ray[2] >= -1e-6:
                continue
            floor = eye - eye[2] / ray[2] * ray
            xy = floor[:2]
            if (np.linalg.norm(floor - eye) > reach and 0.3 < np.linalg.norm(xy) < 1.4
                    and np.min(np.linalg.norm(avoid[:, :2] - xy, axis=1)) > 0.3):
                break
        else:
            dropped += 1
            continue
        R = make_T(axis_angle_to_R([0.0, 0.0, 1.0], yaw))
        if standing:
            T = make_T(t=[xy[0], xy[1], length / 2 + radius]) @ R
        else:
            T = make_T(t=[xy[0], xy[1], radius]) @ R @ make_T(axis_angle_to_R([1.0, 0.0, 0.0], np.pi / 2))
        out.append(Distractor("capsule", length, T, Surface("plain", colour, colour, 1.0, 0.4), radius=radius))
    return out, dropped
