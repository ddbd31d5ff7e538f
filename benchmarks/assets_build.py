"""Asset build time: cold (empty syneepose cache, warm pip cache) and the no-op second run.

Prints figures; asserts nothing. Run: `make bench` or `.venv/bin/python benchmarks/assets_build.py`.
"""

import os
import tempfile
import time
from pathlib import Path

from syneepose.robots.build import build_assets


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["SYNEEPOSE_CACHE"] = str(Path(tmp) / "cache")  # wheels re-fetched from pip's cache
        t0 = time.perf_counter()
        report = build_assets(Path(tmp) / "assets", log=lambda *_: None)
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        again = build_assets(Path(tmp) / "assets", log=lambda *_: None)
        warm = time.perf_counter() - t0
    print(f"assets cold build: {cold:.1f} s ({len(report.parts)} parts, {len(report.configs)} configurations, "
          f"{len(report.models)} models)")
    print(f"assets second run: {warm:.2f} s (did work: {again.did_work})")


if __name__ == "__main__":
    main()
