"""The robot catalogue (`catalog.yaml`) as typed records, and configuration names `ARM+EE`."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import yaml

from kernel.errors import UserError
from kernel.settings import comma_list
from kernel.transforms import xyz_rpy_to_T
from syneepose.robots.model import Mimic

CATALOG_PATH = Path(__file__).with_name("catalog.yaml")


@dataclass(frozen=True)
class Source:
    name: str
    pip: str  # requirement, e.g. robosuite==1.5.2
    licence: str
    licence_files: tuple[str, ...]
    extract: tuple[str, ...]  # path prefixes inside the wheel

    @property
    def dist(self) -> str:
        return self.pip.split("==")[0]

    @property
    def version(self) -> str:
        return self.pip.split("==")[1]


@dataclass(frozen=True)
class Part:
    """Fields shared by arms and end-effectors: where the model comes from."""

    name: str
    source: str
    format: str  # "mjcf" or "urdf"
    file: str  # path inside the extracted source
    packages: tuple[tuple[str, str], ...] = ()  # URDF package:// roots
    compiler_angle: str | None = None  # for MJCF fragments that rely on the including model


@dataclass(frozen=True)
class Arm(Part):
    base_link: str = ""
    flange_link: str = ""
    joints: tuple[str, ...] = ()
    home: tuple[float, ...] = ()
    limits: tuple[tuple[float, float], ...] = ()
    keep_below: str | None = None


@dataclass(frozen=True)
class EndEffector(Part):
    obj_id: int = 0
    mount_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    canonical: tuple[tuple[str, float], ...] = ()
    mimic: tuple[tuple[str, Mimic], ...] = ()
    tcp: tuple[float, float, float] | None = None
    symmetries: tuple[tuple[str, int], ...] = ()  # (axis, order); order 0 = continuous

    @property
    def T_mount_source(self) -> np.ndarray:
        return xyz_rpy_to_T(self.mount_xyz, self.mount_rpy)


@dataclass(frozen=True)
class Catalog:
    sources: dict
    arms: dict
    end_effectors: dict

    def arm(self, name: str) -> Arm:
        if name not in self.arms:
            raise UserError(f"unknown arm {name!r}; known arms: {', '.join(self.arms)}")
        return self.arms[name]

    def end_effector(self, name: str) -> EndEffector:
        if name not in self.end_effectors:
            raise UserError(f"unknown end-effector {name!r}; known end-effectors: {', '.join(self.end_effectors)}")
        return self.end_effectors[name]

    def parse_end_effectors(self, text: str | None) -> list[str]:
        """Comma-separated end-effector names (None -> all), validated."""
        if text is None:
            return list(self.end_effectors)
        return comma_list(text, "--ee", "end-effector", f"known: {', '.join(self.end_effectors)}, or leave it "
                          "out for all", self.end_effector)

    def part(self, name: str) -> Part:
        return self.arms[name] if name in self.arms else self.end_effector(name)

    @property
    def configurations(self) -> list[str]:
        return [f"{a}+{e}" for a in self.arms for e in self.end_effectors]

    def split(self, config: str) -> tuple[Arm, EndEffector]:
        """`ur5e+robotiq_2f85` -> (arm, end-effector), with an error that lists what exists."""
        if config.count("+") != 1:
            raise UserError(f"configuration {config!r} is not of the form ARM+EE, e.g. ur5e+robotiq_2f85")
        arm, ee = config.split("+")
        return self.arm(arm), self.end_effector(ee)

    def parse_configs(self, text: str | None) -> list[str]:
        """Comma-separated ARM+EE names (None or 'all' -> all 18), validated."""
        if text is None or text.strip() in ("", "all"):
            return self.configurations
        return comma_list(text, "--robots", "configuration", "give ARM+EE names, e.g. ur5e+robotiq_2f85, or leave "
                          "it out for all 18", self.split)


def _part_fields(name: str, entry: dict) -> dict:
    fmt = entry.get("format")
    if fmt not in ("mjcf", "urdf"):
        raise UserError(f"catalogue entry {name!r}: format must be mjcf or urdf, not {fmt!r}")
    return dict(
        name=name,
        source=entry["source"],
        format=fmt,
        file=entry["file"],
        packages=tuple(sorted((entry.get("packages") or {}).items())),
        compiler_angle=entry.get("compiler_angle"),
    )


def _symmetry(name: str, s: dict) -> tuple[str, int]:
    axis, order = s.get("axis"), s.get("order", 0)
    if axis not in ("x", "y", "z") or not isinstance(order, int) or order == 1 or order < 0:
        raise UserError(f"catalogue entry {name!r}: symmetry {s} needs axis x|y|z and order 0 (continuous) or >= 2")
    return axis, order


def parse_catalog(data: dict) -> Catalog:
    try:
        sources = {
            n: Source(n, e["pip"], e["licence"], tuple(e["licence_files"]), tuple(e["extract"]))
            for n, e in data["sources"].items()
        }
        arms = {}
        for n, e in data["arms"].items():
            arms[n] = Arm(
                **_part_fields(n, e),
                base_link=e["base_link"],
                flange_link=e["flange_link"],
                joints=tuple(e["joints"]),
                home=tuple(float(v) for v in e["home"]),
                limits=tuple((float(lo), float(hi)) for lo, hi in e["limits"]),
                keep_below=e.get("keep_below"),
            )
            if not (len(arms[n].joints) == len(arms[n].home) == len(arms[n].limits)):
                raise UserError(f"catalogue arm {n!r}: joints, home and limits must have the same length")
        ees = {}
        for n, e in data["end_effectors"].items():
            mount = e.get("mount") or {}
            ees[n] = EndEffector(
                **_part_fields(n, e),
                obj_id=int(e["obj_id"]),
                mount_xyz=tuple(float(v) for v in mount.get("xyz", (0, 0, 0))),
                mount_rpy=tuple(float(v) for v in mount.get("rpy", (0, 0, 0))),
                canonical=tuple((k, float(v)) for k, v in (e.get("canonical") or {}).items()),
                mimic=tuple(
                    (k, Mimic(m["joint"], float(m.get("multiplier", 1.0)), float(m.get("offset", 0.0))))
                    for k, m in (e.get("mimic") or {}).items()
                ),
                tcp=None if e.get("tcp") is None else tuple(float(v) for v in e["tcp"]),
                symmetries=tuple(_symmetry(n, s) for s in (e.get("symmetries") or [])),
            )
    except KeyError as exc:
        raise UserError(f"robot catalogue is missing the key {exc}") from exc
    for part in (*arms.values(), *ees.values()):
        if part.source not in sources:
            raise UserError(f"catalogue entry {part.name!r} names unknown source {part.source!r}")
    ids = [e.obj_id for e in ees.values()]
    if len(set(ids)) != len(ids):
        raise UserError(f"catalogue end-effector obj_ids repeat: {ids}")
    return Catalog(sources, arms, ees)


@lru_cache(maxsize=None)
def load_catalog(path: Path = CATALOG_PATH) -> Catalog:
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise UserError(f"cannot read robot catalogue {path}: {exc}") from exc
    return parse_catalog(data)
