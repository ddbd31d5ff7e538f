"""Which Cycles GPU backend `--device gpu` renders on, and which GPU each local worker is pinned to.

Both are plain data in, data out, so that they are tested without a GPU and without bpy: the bpy side
(syneepose/blender/scene.py) only lists the devices and switches the backend on, and the GPUs of a machine
are counted in the parent from its environment and `nvidia-smi -L`, never by importing bpy there.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass
from typing import Mapping

from kernel.errors import UserError

# Fastest first: OptiX runs Cycles on NVIDIA's RT cores, CUDA on the same cards without them; HIP (AMD),
# oneAPI (Intel) and Metal (Apple) are the only backend of their vendor's cards.
GPU_BACKENDS = ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL")

# What pins a worker to one GPU, read in this order as the GPUs a scheduler or the user left visible:
# CUDA_VISIBLE_DEVICES for Cycles' OptiX and CUDA backends (NVIDIA), HIP_VISIBLE_DEVICES for HIP (AMD); Ray
# sets the same two for a task's GPUs. oneAPI and Metal are not pinned: one worker renders on all their GPUs.
VISIBLE_VARIABLES = ("CUDA_VISIBLE_DEVICES", "HIP_VISIBLE_DEVICES")
NVIDIA_SMI = "nvidia-smi -L"


def gpu_backend(found: dict[str, list[str]]) -> str:
    """The first backend in GPU_BACKENDS order under which Cycles lists a GPU (`found`: backend -> the
    names of its GPUs); one clear line when there is none."""
    for backend in GPU_BACKENDS:
        if found.get(backend):
            return backend
    raise UserError("--device gpu: Cycles finds no GPU on this machine; render with --device cpu")


@dataclass(frozen=True)
class VisibleGpus:
    """The GPUs a process started here may use, named as `variable` names them, and who said so."""

    variable: str
    ids: tuple[str, ...]
    source: str  # "CUDA_VISIBLE_DEVICES='2,3'" or NVIDIA_SMI


def visible_gpus(environ: Mapping[str, str], nvidia_smi_list: str | None) -> VisibleGpus | None:
    """The GPUs a scheduler or the user left visible (VISIBLE_VARIABLES, respected as given), else those
    `nvidia-smi -L` lists (`nvidia_smi_list`: its output, None where it is not installed); None when
    neither tells, e.g. AMD cards without HIP_VISIBLE_DEVICES, or a Mac."""
    for variable in VISIBLE_VARIABLES:
        if variable in environ:
            return VisibleGpus(variable, _listed(environ[variable]), f"{variable}={environ[variable]!r}")
    if nvidia_smi_list is None:
        return None
    ids = tuple(re.findall(r"^GPU (\d+):", nvidia_smi_list, re.MULTILINE))  # MIG lines are indented: not GPUs
    return VisibleGpus("CUDA_VISIBLE_DEVICES", ids, NVIDIA_SMI)


def _listed(value: str) -> tuple[str, ...]:
    """A *_VISIBLE_DEVICES list as the runtimes read it: "" or NoDevFiles (a scheduler's "no GPU") is
    none, and a negative index (the idiom -1) hides itself and every GPU after it."""
    ids = []
    for entry in value.split(","):
        entry = entry.strip()
        if entry in ("", "NoDevFiles") or entry.startswith("-"):
            break
        ids.append(entry)
    return tuple(ids)


def nvidia_smi() -> str | None:
    """What `nvidia-smi -L` prints, a line per NVIDIA GPU; "" when it fails (no driver), None where it is
    not installed."""
    if shutil.which("nvidia-smi") is None:
        return None
    try:
        return subprocess.run(NVIDIA_SMI.split(), capture_output=True, text=True, timeout=60).stdout
    except (OSError, subprocess.TimeoutExpired):
        return ""


def worker_environments(gpus: str | None, workers: int | None,
                        visible: VisibleGpus | None) -> list[dict[str, str]]:
    """The variables each local worker of `--device gpu` starts with: by default one worker per GPU, each
    pinned to its own, so that each renders whole frames and the part of a frame that is not path tracing
    (scene sync, BVH build, writes) overlaps across GPUs instead of idling them; `workers` spreads that many
    over the GPUs in turn. `gpus` is --gpus: None or "all", or indices among the visible GPUs, 0 first.
    Where the GPUs cannot be counted the workers are not pinned, and Cycles in each uses every GPU it
    lists, or says in one line that it lists none."""
    indices = None if gpus in (None, "all") else _indices(gpus)
    if visible is None:
        if indices is not None:
            raise UserError(f"--gpus {gpus}: cannot count this machine's GPUs (no nvidia-smi; CUDA_VISIBLE_DEVICES "
                            "and HIP_VISIBLE_DEVICES unset); list them in one, e.g. HIP_VISIBLE_DEVICES=0,1 for two "
                            "AMD cards")
        return [{} for _ in range(workers or 1)]
    count = len(visible.ids)
    if not count:
        raise UserError(f"--device gpu: no GPU found ({visible.source}); render with --device cpu")
    if indices is not None and max(indices) >= count:
        raise UserError(f"--gpus {gpus}: this machine shows {count} GPU{'s' * (count > 1)} ({visible.source}); "
                        f"give indices below {count}, or all")
    chosen = visible.ids if indices is None else [visible.ids[i] for i in indices]
    # nvidia-smi numbers by PCI bus, CUDA unless told fastest first: tell it, so that index i is nvidia-smi's
    order = {"CUDA_DEVICE_ORDER": "PCI_BUS_ID"} if visible.source == NVIDIA_SMI else {}
    pinned = [{visible.variable: gpu, **order} for gpu in chosen]
    return [pinned[i % len(pinned)] for i in range(workers or len(pinned))]


def _indices(text: str) -> list[int]:
    try:
        indices = [int(v) for v in text.split(",")]
    except ValueError:
        raise UserError(f"--gpus {text!r}: give all or GPU indices such as 0,1,3") from None
    if min(indices) < 0 or len(set(indices)) < len(indices):
        raise UserError(f"--gpus {text}: give each GPU once, by its index from 0 (--workers puts more on each)")
    return indices
