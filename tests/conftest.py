"""Shared fixtures: the built robot assets (built once per session by `make assets` or here)."""

from pathlib import Path

import pytest

from syneepose import paths


@pytest.fixture(scope="session")
def assets() -> Path:
    from syneepose.robots.build import build_assets

    build_assets(log=lambda *_: None)
    return paths.assets_dir()


@pytest.fixture(scope="session")
def catalog():
    from syneepose.robots.catalog import load_catalog

    return load_catalog()
