"""Where built assets live: `$SYNEEPOSE_ASSETS`, else `assets/` at the repository root."""

from __future__ import annotations

import os
from pathlib import Path

import yaml

from kernel.dataset import MODELS, MODELS_EVAL
from kernel.errors import UserError


def assets_dir() -> Path:
    if os.environ.get("SYNEEPOSE_ASSETS"):
        return Path(os.environ["SYNEEPOSE_ASSETS"])
    return Path(__file__).resolve().parents[1] / "assets"


def part_dir(name: str, root: Path | None = None) -> Path:
    return (root or assets_dir()) / "robots" / "parts" / name


def part_urdf(name: str, root: Path | None = None) -> Path:
    return part_dir(name, root) / f"{name}.urdf"


def config_urdf(config: str, root: Path | None = None) -> Path:
    return (root or assets_dir()) / "robots" / f"{config}.urdf"


def models_dir(root: Path | None = None) -> Path:
    return (root or assets_dir()) / MODELS


def models_eval_dir(root: Path | None = None) -> Path:
    """BOP's `models_eval/`: the uniformly resampled models that pose errors are computed on."""
    return (root or assets_dir()) / MODELS_EVAL


def named_yaml(name_or_path: str, folder: Path, kind: str) -> tuple[Path, dict]:
    """A YAML file given by name (`folder/<name>.yaml`, e.g. a preset) or by path, and its contents."""
    path = Path(name_or_path)
    if not path.suffix:
        path = Path(folder) / f"{name_or_path}.yaml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in Path(folder).glob("*.yaml")))
        raise UserError(f"{kind} {name_or_path!r} not found; known {kind}s: {known}, or give a YAML path")
    try:
        return path, yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise UserError(f"{kind} {path} is not valid YAML: {exc}") from exc
