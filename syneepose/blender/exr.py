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


def linear_to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 transfer function (Blender's 'Standard' view), to 8 bits."""
    rgb = np.clip(rgb, 0.0, 1.0)
    srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1.0 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def srgb_to_linear(c):
    c = np.asarray(c, dtype=float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
