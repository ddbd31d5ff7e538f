"""Where built assets live: `$SYNEEPOSE_ASSETS`, else `assets/` at the repository root."""

from __future__ import annotations

import os
from pathlib import Path


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
    return (root or assets_dir()) / "models"
