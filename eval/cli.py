"""How the evaluator's commands end: a user mistake is one `error:` line and exit 2, never a traceback."""

from __future__ import annotations

import sys
from typing import Callable

from syneepose.errors import UserError


def run_command(action: Callable[[], str]) -> int:
    """Runs `action` and prints the one-line report it returns; exit 0, 2 (UserError) or 130 (Ctrl-C)."""
    try:
        report = action()
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    print(report)
    return 0
