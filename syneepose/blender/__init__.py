"""The only bpy code of the project: build a Blender scene from a plain scene description, render
it with Cycles and hand back numpy arrays. Import its modules only inside render worker processes."""

from kernel.errors import UserError

try:
    import bpy  # noqa: F401 - loaded here once, so a broken install is one line, not a worker traceback
except (ImportError, OSError) as exc:
    raise UserError(f"Blender's Python module does not load ({exc}); `make dataset` installs bpy==5.0.1 into "
                    ".venv, and a missing system library named here is an apt package (e.g. libxrender1, "
                    "libxkbcommon0, libsm6, libgl1)") from None
