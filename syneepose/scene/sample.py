"""Seeded domain randomisation: a preset (typed ranges, syneepose/preset.py) + a seed -> a SegmentSpec.

Everything here is pure numpy; the same (preset, config, stream, seed) gives the same spec.
"""

from __future__ import annotations

import numpy as np

from kernel.transforms import make_T
from syneepose.colour import srgb_to_linear
from syneepose.preset import Preset
from syneepose.scene.spec import Distractor, Light, Plane, SegmentSpec, Surface


def rng_for(seed: int, config: str, stream: int) -> np.random.Generator:
    """Independent stream per segment, stable across runs and machines."""
    key = [seed, stream] + [ord(c) for c in config]
    return np.random.default_rng(np.random.SeedSequence(key))


def uniform(rng: np.random.Generator, r) -> float:
    lo, hi = r
    return float(rng.uniform(lo, hi))


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV camera pose (z forward, y down) at `eye` looking at `target`."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, (1.0, 0.0, 0.0))
    x /= np.linalg.norm(x)
    return make_T(np.stack([x, np.cross(z, x), z], 1), eye)


def kelvin_to_rgb(kelvin: float) -> tuple[float, float, float]:
    """Black-body colour (Tanner Helland's fit), normalised to max 1, in linear RGB."""
    t = kelvin / 100.0
    r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
    g = 99.4708025861 * np.log(t) - 161.1195681661 if t <= 66 else 288.1221695283 * (t - 60) ** -0.0755148492
    b = 255.0 if t >= 66 else (0.0 if t <= 19 else 138.5177312231 * np.log(t - 10) - 305.0447927307)
    rgb = np.clip(np.array([r, g, b]) / 255.0, 0.0, 1.0)
    rgb = srgb_to_linear(rgb)
    return tuple(float(c) for c in rgb / rgb.max())


def _K(hfov_deg: float, width: int, height: int, dx: float = 0.0, dy: float = 0.0) -> np.ndarray:
    f = width / 2 / np.tan(np.deg2rad(hfov_deg) / 2)
    return np.array([[f, 0.0, (width - 1) / 2 + dx * width], [0.0, f, (height - 1) / 2 + dy * height], [0.0, 0.0, 1.0]])


def intrinsics(rng, preset: Preset, width: int, height: int) -> np.ndarray:
    """Square pixels; focal length from a horizontal field of view; principal point jittered."""
    fov = uniform(rng, preset.camera.hfov_deg)
    jitter = preset.camera.principal_jitter
    dx, dy = rng.uniform(-jitter, jitter), rng.uniform(-jitter, jitter)
    return _K(fov, width, height, dx, dy)


def nominal_intrinsics(preset: Preset, width: int, height: int) -> np.ndarray:
    """The camera the sampler varies around (mid-range field of view, centred principal point): BOP's
    camera.json for a data set whose K differs per segment."""
    return _K(float(np.mean(preset.camera.hfov_deg)), width, height)


def random_surface(rng, preset: Preset) -> Surface:
    value = preset.backdrop.value
    return Surface(
        kind=str(rng.choice(list(preset.backdrop.kinds))),
        color_a=tuple(float(c) for c in rng.uniform(*value, 3) ** 2.2),
        color_b=tuple(float(c) for c in rng.uniform(*value, 3) ** 2.2),
        scale=uniform(rng, preset.backdrop.scale),
        roughness=uniform(rng, [0.2, 0.9]),
    )


def backdrop(rng, preset: Preset, images: list[str]) -> list[Plane]:
    """A floor under the robot and 0-3 walls around it, each with its own surface."""
    size = preset.backdrop.extent
    planes = [Plane(make_T(t=[0.0, 0.0, -0.001]), (size, size), random_surface(rng, preset))]
    n_walls = int(rng.integers(*preset.backdrop.walls, endpoint=True))
    for k in rng.permutation(4)[:n_walls]:
        yaw = k * np.pi / 2
        distance = uniform(rng, preset.backdrop.wall_distance)
        # The wall's normal (+z of the plane) faces the robot.
        direction = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        z = -direction
        x = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        R = make_T(np.stack([x, np.cross(z, x), z], 1), direction * distance + [0, 0, size / 4])
        surface = random_surface(rng, preset)
        if images and rng.random() < 0.5:
            surface.image = str(rng.choice(images))
        planes.append(Plane(R, (size, size / 2), surface))
    return planes


def lights(rng, preset: Preset, target: np.ndarray) -> list[Light]:
    p = preset.lights
    out = []
    for _ in range(int(rng.integers(*p.count, endpoint=True))):
        kind = str(rng.choice(list(p.kinds)))
        azimuth, elevation = rng.uniform(0, 2 * np.pi), np.deg2rad(uniform(rng, p.elevation_deg))
        distance = uniform(rng, p.distance)
        eye = target + distance * np.array([np.cos(azimuth) * np.cos(elevation),
                                            np.sin(azimuth) * np.cos(elevation), np.sin(elevation)])
        T = look_at(eye, target) @ np.diag([1.0, -1.0, -1.0, 1.0])  # Blender lights shine along -z
        color = kelvin_to_rgb(uniform(rng, p.kelvin))
        if kind == "SUN":
            energy, size = uniform(rng, p.sun_strength), np.deg2rad(uniform(rng, [0.5, 10]))
        else:
            energy = uniform(rng, p.power_w) * (distance / 2.0) ** 2
            size = uniform(rng, [0.1, 1.0])
        out.append(Light(kind, T, color, energy, size))
    return out


MAX_PLACEMENTS = 100  # places tried per object before it is left out


def distractors(rng, preset: Preset, avoid: np.ndarray) -> tuple[list[Distractor], int]:
    """Objects on the floor, their centres at least 0.3 m from the robot base and the end-effector path (xy);
    an object with no such place in MAX_PLACEMENTS draws is left out. Returns the objects and how many were."""
    p = preset.distractors
    out, dropped = [], 0
    for _ in range(int(rng.integers(*p.count, endpoint=True))):
        for _attempt in range(MAX_PLACEMENTS):
            xy = rng.uniform(-1.5, 1.5, 2)
            if np.linalg.norm(xy) > 0.3 and np.min(np.linalg.norm(avoid[:, :2] - xy, axis=1)) > 0.3:
                break
        else:
            dropped += 1
            continue
        size = uniform(rng, p.size)
        kind = str(rng.choice(["cube", "sphere", "cylinder", "torus"]))
        T = make_T(t=[xy[0], xy[1], size / 2])
        out.append(Distractor(kind, size, T, random_surface(rng, preset)))
    return out, dropped


def sample_segment(rng, preset: Preset, robot, config: str, stream: int, seed: int, q: np.ndarray,
                   width: int, height: int, images: list[str] | None = None,
                   in_view: np.ndarray | None = None) -> SegmentSpec:
    """Camera, lights and backdrop around a given arm trajectory `q` (see motion.py), the camera aimed at the
    mean end-effector position of the frames `in_view` (all by default)."""
    ee_path = robot.T_base_ee(q)[:, :3, 3]
    target = ee_path[in_view].mean(0) if in_view is not None else ee_path.mean(0)
    K = intrinsics(rng, preset, width, height)
    cam = preset.camera
    azimuth = np.deg2rad(uniform(rng, cam.azimuth_deg))
    elevation = np.deg2rad(uniform(rng, cam.elevation_deg))
    distance = uniform(rng, cam.distance)
    eye = target + distance * np.array([np.cos(azimuth) * np.cos(elevation),
                                        np.sin(azimuth) * np.cos(elevation), np.sin(elevation)])
    eye[2] = max(eye[2], 0.05)
    world = preset.world
    world_color = tuple(float(c) for c in rng.uniform(*world.value, 3) ** 2.2)
    world_strength = uniform(rng, world.strength)
    lit = lights(rng, preset, target)
    planes = backdrop(rng, preset, images or [])
    objects, dropped = distractors(rng, preset, ee_path)  # drawn in this order: a seed's segments stay as they were
    return SegmentSpec(config=config, stream=stream, seed=seed, K=K, T_base_cam=look_at(eye, target), q=q,
                       world_color=world_color, world_strength=world_strength, lights=lit, planes=planes,
                       distractors=objects, dropped_distractors=dropped)
