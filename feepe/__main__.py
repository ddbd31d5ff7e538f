"""`python -m feepe calibrate ...`: the camera-to-base calibration of a recording (feepe/calibrate/command.py)."""

import sys

COMMANDS = ("calibrate",)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in COMMANDS:
        print(f"usage: python -m feepe {{{','.join(COMMANDS)}}} ...  (python -m feepe calibrate --help)", file=sys.stderr)
        return 2
    from feepe.calibrate.command import main as calibrate
    return calibrate(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
