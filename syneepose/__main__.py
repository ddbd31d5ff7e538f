"""Command line: `python -m syneepose assets [--out DIR] [--robots ARM+EE,...] [--force]`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from syneepose.errors import UserError


def _assets(args) -> None:
    from syneepose.robots.build import build_assets
    from syneepose.robots.catalog import load_catalog

    configs = load_catalog().parse_configs(args.robots)
    report = build_assets(Path(args.out) if args.out else None, configs, force=args.force)
    if report.did_work:
        print(f"assets: built {len(report.parts)} parts, {len(report.configs)} configurations, "
              f"{len(report.models)} end-effector models in {report.seconds:.1f} s")
    else:
        print(f"assets: up to date ({len(configs)} configurations), nothing to do")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m syneepose", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("assets", help="build the robot URDFs and the BOP end-effector models")
    p.add_argument("--out", help="assets folder (default: $SYNEEPOSE_ASSETS or ./assets)")
    p.add_argument("--robots", help="comma-separated ARM+EE configurations (default: all 18)")
    p.add_argument("--force", action="store_true", help="rebuild even when up to date")
    p.set_defaults(func=_assets)
    args = parser.parse_args(argv)
    try:
        args.func(args)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
