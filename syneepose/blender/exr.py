"""Read Blender's multilayer (multi-part since Blender 5) EXR output into numpy, without bpy."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def read_passes(path: Path) -> dict[str, np.ndarray]:
    """{'<layer>.<pass>': array}; RGBA passes come as (H, W, 4), vector passes (Normal: channels X, Y, Z)
    as (H, W, 3), scalar passes (Depth's one Z channel, Object Index's one X) as (H, W)."""
    import OpenEXR

    channels = {}
    with OpenEXR.File(str(path)) as f:
        for part in f.parts:
            for name, channel in part.channels.items():
                channels[name] = np.array(channel.pixels)
    out = {}
    for name, pixels in channels.items():
        key, _, axis = name.rpartition(".")
        if axis in ("X", "Y", "Z", "V") and key:
            vector = [f"{key}.{a}" for a in "XYZ"]
            out[key] = np.stack([channels[v] for v in vector], -1) if all(v in channels for v in vector) else pixels
        else:
            out[name] = pixels
    return out
