"""How commands end (kernel/cli.py): a refused file operation is one line that says what happened, told by
errno, and SYNEEPOSE_DEBUG=1 puts the traceback above an error line, in every command."""

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

from kernel.cli import DEBUG_ENV, run_command
from kernel.errors import UserError

REPO = Path(__file__).resolve().parents[1]


def _refused(code: int, strerror: str):
    def action():
        raise OSError(code, strerror, "/data/out/rgb/000003.png")
    return action


@pytest.mark.parametrize("code, strerror, said, mend", [
    (errno.ENOSPC, "No space left on device", "no space left on the device", "free space"),
    (errno.EDQUOT, "Disk quota exceeded", "the disk quota is used up", "free space"),
    (errno.EACCES, "Permission denied", "permission denied", "fix the permissions"),
    (errno.EPERM, "Operation not permitted", "operation not permitted", "fix the permissions"),
    (errno.EROFS, "Read-only file system", "read-only file system", "write somewhere writable"),
])
def test_a_full_disk_or_a_refused_permission_is_named(code, strerror, said, mend, capsys, monkeypatch):
    monkeypatch.delenv(DEBUG_ENV, raising=False)
    assert run_command(_refused(code, strerror)) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: /data/out/rgb/000003.png: {said}; {mend}, then run")


def test_another_os_error_says_what_it_was_not_disk_or_permissions(capsys, monkeypatch):
    monkeypatch.delenv(DEBUG_ENV, raising=False)
    assert run_command(_refused(errno.EIO, "Input/output error")) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: /data/out/rgb/000003.png: Input/output error (EIO); ")
    assert "space" not in err and "permission" not in err and f"{DEBUG_ENV}=1" in err

    def no_errno():
        raise ConnectionRefusedError("the cluster did not answer")
    assert run_command(no_errno) == 1
    assert capsys.readouterr().err.startswith("error: the cluster did not answer (no errno); ")


@pytest.mark.parametrize("value, traceback", [("1", True), ("0", False), ("", False)])
def test_the_debug_switch_puts_the_traceback_above_the_line(value, traceback, capsys, monkeypatch):
    monkeypatch.setenv(DEBUG_ENV, value)

    def mistake():
        try:
            {}["key"]
        except KeyError as exc:
            raise UserError("a mistake a user can fix") from exc
    for action, code, line, cause in ((mistake, 2, "error: a mistake a user can fix", "KeyError: 'key'"),
                                      (_refused(errno.ENOSPC, "No space left on device"), 1, "error: /data/out/rgb",
                                       "OSError: [Errno 28]")):
        assert run_command(action) == code
        err = capsys.readouterr().err
        assert err.splitlines()[-1].startswith(line)
        assert ("Traceback (most recent call last)" in err) == traceback and (cause in err) == traceback


def test_every_command_honours_the_switch(tmp_path):
    """A real command's user mistake: one line without the switch, the traceback with it."""
    command = [sys.executable, "-m", "eval.overlays", str(tmp_path / "no_run"), "--out", str(tmp_path / "out")]
    env = {k: v for k, v in os.environ.items() if k != DEBUG_ENV}
    plain = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True)
    debug = subprocess.run(command, cwd=REPO, env={**env, DEBUG_ENV: "1"}, capture_output=True, text=True)
    assert plain.returncode == debug.returncode == 2
    assert plain.stderr.count("\n") == 1 and "summary.json: missing" in plain.stderr
    assert "Traceback" in debug.stderr and debug.stderr.splitlines()[-1] == plain.stderr.strip()
