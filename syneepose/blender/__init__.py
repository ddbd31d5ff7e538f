"""The project's bpy code: build a Blender scene from a plain scene description (syneepose/scene/spec.py),
render segments, templates and the stereo IR pair with Cycles and hand back numpy arrays; Voxel Remesh for
models_eval/; the flat-wall stereo noise check (`python -m syneepose.blender.flat_patch`). bpy holds global
state and leaks over long loops, so the generator imports these modules only in spawned processes (render
workers, the models_eval remesh); importing the package loads bpy once, so a broken install is one line."""

from kernel.errors import UserError

try:
    import bpy  # noqa: F401 - loaded here once, so a broken install is one line, not a worker traceback
except (ImportError, OSError) as exc:
    raise UserError(f"Blender's Python module does not load ({exc}); `make dataset` installs bpy==5.0.1 into "
                    ".venv, and a missing system library named here is an apt package (e.g. libxrender1, "
                    "libxkbcommon0, libsm6, libgl1)") from None
