"""A preset YAML (`scenes/*.yaml`) as one validated, typed object: every range the scene sampler draws from,
the render defaults and the template defaults. Validated once, here, at every level: unknown keys, wrong
types, inverted or empty ranges and sizes no machine renders are refused with one line naming the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field

from kernel.errors import UserError
from kernel.settings import Section, int_range, number_range, validate
from syneepose import paths

SCENES_DIR = Path(__file__).resolve().parents[1] / "scenes"
SURFACE_KINDS = ("plain", "noise", "voronoi", "wave", "brick", "checker")  # Blender texture nodes (blender/scene.py)
EXAMPLE = "scenes/mini.yaml"
MAX_SIDE_PX = 8192  # a render side beyond this is a typo, not a data set (100000x100000 would never finish)


PREFILTERS = ("accurate", "fast", "none")  # Cycles' denoising_prefilter: how the denoiser cleans its albedo and normal
DEFAULT_PREFILTER = "accurate"  # Cycles' own default: every data set before issue 36 was denoised with it


class Render(Section):
    denoise: bool = False
    denoise_prefilter: Literal[PREFILTERS] = DEFAULT_PREFILTER
    max_bounces: int = Field(12, ge=0, le=1024)


class Camera(Section):
    hfov_deg: number_range(1.0, 179.0)
    principal_jitter: float = Field(0.0, ge=0.0, le=0.5)  # fraction of the image size
    distance: number_range(0.0, exclusive_low=True)  # metres from the mean end-effector position
    azimuth_deg: number_range(-360.0, 360.0) = (-180.0, 180.0)
    elevation_deg: number_range(-90.0, 90.0) = (5.0, 60.0)
    min_visible: float = Field(0.5, ge=0.0, le=1.0)  # fraction of end-effector points unoccluded, every frame
    margin: float = Field(0.02, ge=0.0, lt=0.5)  # fraction of the image size kept from the border


class Motion(Section):
    waypoints: int = Field(ge=1, le=1000)
    spread: float = Field(ge=0.0)
    clearance: float = Field(0.1, ge=0.0)


class Lights(Section):
    count: int_range(0, 64)
    kinds: tuple[Literal["AREA", "POINT", "SUN"], ...] = Field(("AREA", "POINT", "SUN"), min_length=1)
    kelvin: number_range(1000.0, 40000.0) = (2700.0, 7500.0)
    power_w: number_range(0.0) = (40.0, 300.0)
    sun_strength: number_range(0.0) = (0.5, 3.0)
    elevation_deg: number_range(-90.0, 90.0) = (20.0, 80.0)
    distance: number_range(0.0, exclusive_low=True) = (1.5, 4.0)


class World(Section):
    value: number_range(0.0, 1.0) = (0.0, 0.3)
    strength: number_range(0.0) = (0.2, 1.5)


class Backdrop(Section):
    kinds: tuple[Literal[SURFACE_KINDS], ...] = Field(SURFACE_KINDS, min_length=1)
    value: number_range(0.0, 1.0) = (0.05, 0.8)
    scale: number_range(0.0, exclusive_low=True) = (1.0, 20.0)
    walls: int_range(0, 4) = (0, 3)
    wall_distance: number_range(0.0, exclusive_low=True) = (1.5, 3.0)
    extent: float = Field(8.0, gt=0.0)


class Distractors(Section):
    count: int_range(0, 64) = (0, 0)
    size: number_range(0.0, exclusive_low=True) = (0.05, 0.3)


class Occluder(Section):
    """An object that crosses the line of sight to the end-effector (scene/hard.py)."""
    size: number_range(0.0, exclusive_low=True) = (0.06, 0.15)
    frames: number_range(0.0, 1.0, exclusive_low=True) = (0.2, 0.4)  # share of the frames it covers the end-effector
    between: number_range(0.0, 1.0, exclusive_low=True) = (0.65, 0.85)  # where on the camera-to-end-effector line


class Exit(Section):
    """The end-effector out of the image for a run of frames (at the start, middle or end of the segment)."""
    frames: number_range(0.0, 1.0, exclusive_low=True) = (0.2, 0.4)


class ArmColoured(Section):
    """Capsules as long and thick as links, each in one of the arm's colours, lying or standing in view behind
    the robot."""
    count: int_range(1, 16) = (1, 2)
    length: number_range(0.0, exclusive_low=True) = (0.2, 0.5)
    radius: number_range(0.0, exclusive_low=True) = (0.03, 0.07)


class Hard(Section):
    """Hard cases for mask-free estimation (issue 34), each off unless given; `mini` draws none."""
    occluder: Occluder | None = None
    exit: Exit | None = None
    arm_coloured: ArmColoured | None = None


class Templates(Section):
    views: int = Field(80, ge=1, le=10000)  # x inplane 12: the paper's 960 templates
    inplane: int = Field(12, ge=1, le=360)
    resolution: int = Field(128, ge=8, le=4096)
    samples: int = Field(8, ge=1, le=65536)


class Marker(Section):
    """A ChArUco board bolted to the end-effector (scene/marker.py); its mount: clearance and height (m)."""
    dictionary: str = "DICT_4X4_50"
    squares: tuple[Annotated[int, Field(ge=2, le=100)], Annotated[int, Field(ge=2, le=100)]] = (4, 5)
    square: float = Field(0.05, gt=0.0)
    marker: float = Field(0.037, gt=0.0)
    margin: float = Field(0.01, ge=0.0)
    clearance: float | None = Field(None, ge=0.0)
    height: float | None = Field(None, ge=0.0)


class Stations(Section):
    """Calibration stations (scene/stations.py) instead of a trajectory."""
    max_tilt_deg: float = Field(40.0, gt=0.0, lt=90.0)  # between the board's normal and the camera direction
    pool: int = Field(300, ge=1, le=100000)  # arm poses drawn per camera


class Preset(Section):
    name: str
    segments: int = Field(ge=1, le=100000)  # per configuration
    frames: int = Field(ge=1, le=100000)  # per segment
    resolution: tuple[Annotated[int, Field(ge=8, le=MAX_SIDE_PX)], Annotated[int, Field(ge=8, le=MAX_SIDE_PX)]]
    samples: int = Field(ge=1, le=65536)
    render: Render = Render()
    camera: Camera
    motion: Motion
    lights: Lights
    world: World = World()
    backdrop: Backdrop
    distractors: Distractors = Distractors()
    hard: Hard | None = None
    templates: Templates = Templates()
    marker: Marker | None = None
    stations: Stations | None = None

    def render_settings(self, **run) -> RenderSettings:
        """The preset's render choices with the run's (`run`: RenderSettings' device, depth, threads, ...)."""
        from syneepose.scene.spec import RenderSettings  # spec imports this module (DEFAULT_PREFILTER)

        return RenderSettings(*self.resolution, self.samples, self.render.denoise, self.render.max_bounces,
                              denoise_prefilter=self.render.denoise_prefilter, **run)

    def digest_content(self) -> dict:
        """Every value that fixes the rendered frames, defaults included: two YAMLs that render alike compare
        equal. Not `templates`: a template set records its own recipe (kernel/template_set.py), and mini's
        going from 240 to 960 templates must not make its frames "other settings". The prefilter counts only
        when it is not Cycles' default, the one every preset rendered with before it could be chosen (issue 36),
        so those data sets keep their digest; `hard` likewise only when given (issue 34)."""
        content = self.model_dump(mode="json", exclude={"templates"})
        if content["render"]["denoise_prefilter"] == DEFAULT_PREFILTER:
            del content["render"]["denoise_prefilter"]
        if content["hard"] is None:
            del content["hard"]
        return content

    def legacy_digest_contents(self) -> list[dict]:
        """What digest_content was before issue 16 (templates included), with this preset's templates and with
        the templates every shipped preset but `paper` had then: scenes recorded that way still resume."""
        before = Templates(views=20, inplane=12, resolution=128, samples=8).model_dump(mode="json")
        return [{**self.digest_content(), "templates": templates}
                for templates in (self.templates.model_dump(mode="json"), before)]


def load_preset(name_or_path: str, overrides: dict | None = None) -> Preset:
    """The preset by name (`scenes/<name>.yaml`) or path. `overrides` ({"frames": 32, ...}: command-line
    flags, None where not given) replace its top-level values and are validated with it."""
    path, raw = paths.named_yaml(name_or_path, SCENES_DIR, "preset")
    if not isinstance(raw, dict):
        raise UserError(f"preset {path}: holds {type(raw).__name__}, not a mapping of settings")
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    return parse_preset({**raw, **given}, str(path), given)


def parse_preset(content: dict, source: str = "preset", flags: dict | None = None) -> Preset:
    return validate(Preset, content, source, flags or {}, EXAMPLE)


HARD_CASES = ("occluder", "exit", "arm_coloured")  # Hard's fields: what `render --hard` names


def with_hard_cases(preset: Preset, names: list[str]) -> Preset:
    """The preset with the named hard cases on (`render --hard`): each with the preset's own settings where its
    `hard:` section has them, else the defaults."""
    current = preset.hard or Hard()
    defaults = {"occluder": Occluder(), "exit": Exit(), "arm_coloured": ArmColoured()}
    hard = current.model_copy(update={n: getattr(current, n) or defaults[n] for n in names})
    return preset.model_copy(update={"hard": hard})


def templates_with(preset: Preset, overrides: dict) -> Templates:
    """The preset's template settings with the command line's (None where not given), validated."""
    given = {k: v for k, v in overrides.items() if v is not None}
    return validate(Templates, {**preset.templates.model_dump(), **given}, f"preset {preset.name}: templates", given,
                    EXAMPLE)
