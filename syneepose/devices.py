"""Which Cycles GPU backend `--device gpu` renders on, chosen from the devices Cycles lists per backend.

The choice is plain data in, a name out, so that it is tested without a GPU and without bpy; the bpy side
(syneepose/blender/scene.py) only lists the devices and switches the backend on.
"""

from __future__ import annotations

from kernel.errors import UserError

# Fastest first: OptiX runs Cycles on NVIDIA's RT cores, CUDA on the same cards without them; HIP (AMD),
# oneAPI (Intel) and Metal (Apple) are the only backend of their vendor's cards.
GPU_BACKENDS = ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL")


def gpu_backend(found: dict[str, list[str]]) -> str:
    """The first backend in GPU_BACKENDS order under which Cycles lists a GPU (`found`: backend -> the
    names of its GPUs); one clear line when there is none."""
    for backend in GPU_BACKENDS:
        if found.get(backend):
            return backend
    raise UserError("--device gpu: Cycles finds no GPU on this machine; render with --device cpu")
