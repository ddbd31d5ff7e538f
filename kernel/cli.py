"""How every command line of the project ends: a user mistake is one `error:` line and exit 2, never a
traceback; the machine refusing a file operation is one line naming the file and what happened (no space
left, no permission, a read-only file system, or the system's own words for anything else) and exit 1;
Ctrl-C is exit 130. With SYNEEPOSE_DEBUG=1 in the environment the traceback comes first, for whoever has to
find the cause behind the line."""

from __future__ import annotations

import errno
import os
import signal
import sys
import traceback
from pathlib import Path
from typing import Callable

from kernel.errors import UserError

DEBUG_ENV = "SYNEEPOSE_DEBUG"  # set (not "0") to print the traceback above an error line
_KEPT = "finished files are kept, half-written ones are not"
# refusals a user can mend, by errno: what happened, and the mend
_REFUSALS = {
    errno.ENOSPC: ("no space left on the device", "free space"),
    errno.EDQUOT: ("the disk quota is used up", "free space"),
    errno.EACCES: ("permission denied", "fix the permissions"),
    errno.EPERM: ("operation not permitted", "fix the permissions"),
    errno.EROFS: ("read-only file system", "write somewhere writable"),
}


def debugging() -> bool:
    """Whether SYNEEPOSE_DEBUG asks for tracebacks."""
    return os.environ.get(DEBUG_ENV, "") not in ("", "0")


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


def refusal(exc: OSError) -> str:
    """The one line for a refused file operation: the file, what happened (told by errno) and the mend."""
    where = f"{exc.filename}: " if exc.filename else ""
    if exc.errno in _REFUSALS:
        what, mend = _REFUSALS[exc.errno]
        return f"{where}{what}; {mend}, then run again ({_KEPT})"
    name = errno.errorcode.get(exc.errno, "no errno")  # errno None (an OSError raised with words alone) too
    return f"{where}{exc.strerror or exc} ({name}); {_KEPT}; {DEBUG_ENV}=1 shows where it happened"


def run_command(action: Callable[[], str | None]) -> int:
    """Runs `action` and prints the report it returns, if any; exit 0, 2 (UserError), 1 (the system refused a
    file operation) or 130 (Ctrl-C)."""
    previous = signal.signal(signal.SIGTERM, _interrupt)  # a scheduler's stop ends the run as Ctrl-C does
    try:
        report = action()
    except UserError as exc:
        _traceback_if_debugging()
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        _traceback_if_debugging()
        print(f"error: {refusal(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    if report:
        print(report)
    return 0


def _traceback_if_debugging() -> None:
    if debugging():
        traceback.print_exc(file=sys.stderr)
