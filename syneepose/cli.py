"""How every command line of the project ends: a user mistake is one `error:` line and exit 2, never a
traceback; Ctrl-C is exit 130."""

from __future__ import annotations

import sys
from typing import Callable

from syneepose.errors import UserError


def run_command(action: Callable[[], str | None]) -> int:
    """Runs `action` and prints the report it returns, if any; exit 0, 2 (UserError) or 130 (Ctrl-C)."""
    try:
        report = action()
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    if report:
        print(report)
    return 0
