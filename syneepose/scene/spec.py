"""The plain description of one segment that the Blender side renders; frames are in the robot base."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from syneepose.preset import DEFAULT_PREFILTER
from syneepose.scene.marker import MarkerBoard


@dataclass
class Surface:
    """A procedural material: two linear-RGB colours mixed by a Blender texture node."""

    kind: str
    color_a: tuple[float, float, float]
    color_b: tuple[float, float, float]
    scale: float
    roughness: float = 0.5
    image: str | None = None  # a user background image replaces the procedural pattern


@dataclass
class Plane:
    T_base_plane: np.ndarray  # plane in its local xy, normal +z
    size: tuple[float, float]
    surface: Surface


@dataclass
class Light:
    kind: str  # "AREA" | "POINT" | "SUN"; Blender lights shine along their local -z
    T_base_light: np.ndarray
    color: tuple[float, float, float]  # linear RGB, from a colour temperature
    energy: float  # W (area, point) or W/m^2 (sun)
    size: float  # m (area side, point radius) or rad (sun angle)


@dataclass
class Distractor:
    kind: str  # "cube" | "sphere" | "cylinder" | "torus" | "capsule"
    size: float  # a capsule's length between its two caps' centres
    T_base_obj: np.ndarray
    surface: Surface
    radius: float | None = None  # a capsule's (scene/hard.py's arm-coloured links)


@dataclass
class Occluder:
    """An object moving through the scene (scene/hard.py): a pose per frame."""

    kind: str  # "cube" | "sphere" | "cylinder"
    size: float
    T_base_obj: np.ndarray  # (n_frames, 4, 4)
    surface: Surface


@dataclass
class SegmentSpec:
    """What the segment shows: the camera, the arm's motion, lights, backdrop, objects and board. `K` is
    for the image size of the RenderSettings it was planned with."""

    config: str
    stream: int  # its random stream (scene/sample.rng_for): fixed by the segment's key, not its scene id
    seed: int
    K: np.ndarray  # (3, 3) OpenCV intrinsics
    T_base_cam: np.ndarray  # (4, 4) OpenCV camera in the robot base, static over the segment
    q: np.ndarray  # (n_frames, n_arm) arm joint positions
    world_color: tuple[float, float, float] = (0.05, 0.05, 0.05)
    world_strength: float = 1.0
    lights: list[Light] = field(default_factory=list)
    planes: list[Plane] = field(default_factory=list)
    distractors: list[Distractor] = field(default_factory=list)
    dropped_distractors: int = 0  # sampled objects left out: no place away from the robot was found
    occluders: list[Occluder] = field(default_factory=list)
    marker: MarkerBoard | None = None  # a ChArUco board bolted to the end-effector (marker hand-eye segments)

    @property
    def n_frames(self) -> int:
        return len(self.q)


IR_RENDERS = ("shaded", "pathtraced")  # the stereo IR pair: shaded from G-buffers (syneepose/ir_shading.py), or by Cycles


@dataclass(frozen=True)
class RenderSettings:
    """How a run renders its segments, beside what each shows (SegmentSpec): the run's choice, the same for
    every segment and never sampled, so planning returns the spec whole and nothing patches it afterwards."""

    width: int
    height: int
    samples: int
    denoise: bool = False
    max_bounces: int = 12
    device: str = "cpu"  # "gpu": Cycles on the first GPU backend found
    depth: str = "exact"  # "stereo" | "both": simulated active-stereo depth (syneepose/stereo.py)
    sensor: str = "d435"  # the stereo sensor's profile: a name in scenes/sensors/ or a YAML path
    threads: int = 0  # Cycles CPU threads; 0: every core of the machine the job runs on
    sensor_render: str | None = None  # one of IR_RENDERS; None: the sensor profile's choice
    denoise_prefilter: str = DEFAULT_PREFILTER  # preset.PREFILTERS: how the denoiser cleans its albedo and normal passes
