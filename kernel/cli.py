"""How every command line of the project ends: a user mistake is one `error:` line and exit 2, never a
traceback; the machine refusing a file operation (disk full, no permission) is one line naming the file and
exit 1; Ctrl-C is exit 130."""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from typing import Callable

from kernel.errors import UserError


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def output_dir(path: Path, flag: str = "--out") -> Path:
    """The folder a command writes to, created; a file of that name or an unwritable parent is one line."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UserError(f"{flag} {path} is a file; give a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot write to {flag} {path}: {exc.strerror}") from None
    return path


def run_command(action: Callable[[], str | None]) -> int:
    """Runs `action` and prints the report it returns, if any; exit 0, 2 (UserError), 1 (the system refused a
    file operation) or 130 (Ctrl-C)."""
    previous = signal.signal(signal.SIGTERM, _interrupt)  # a scheduler's stop ends the run as Ctrl-C does
    try:
        report = action()
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        where = exc.filename or "a file operation"
        print(f"error: {where}: {exc.strerror or exc}; free space or fix the permissions, then run again "
              "(finished files are kept, half-written ones are not)", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    if report:
        print(report)
    return 0
