"""What an engineer judges the calibration by eye with: each frame with the robot's outline at the final
calibration drawn on it (a GIF of the recording and a few stills), beside the transform, its uncertainty,
the verdict and the per-frame residuals, in one HTML page (report.html) that needs no server."""

from __future__ import annotations

import html
from pathlib import Path

import cv2
import numpy as np

from kernel.drawing import EST_COLOUR, caption, draw_outline
from kernel.files import write_atomic, write_gif, write_png

GIF_FRAMES = 48  # at most, evenly over the recording
STILLS = 6
WIDTH = 480  # pictures are scaled down to this width at most


class Overlays:
    """Collects the drawn frames while the check renders them (no frame is held undrawn)."""

    def __init__(self, n_frames: int):
        keep = np.unique(np.linspace(0, n_frames - 1, min(GIF_FRAMES, n_frames)).round().astype(int))
        self.keep, self.drawn, self.index = set(keep.tolist()), [], 0

    def __call__(self, name: str, rgb: np.ndarray, rendered: np.ndarray, residual: str) -> None:
        if self.index in self.keep:
            image = draw_outline(rgb.copy(), rendered > 0, EST_COLOUR, max(1, rgb.shape[1] // 320))
            scale = min(1.0, WIDTH / image.shape[1])
            if scale < 1.0:
                image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            self.drawn.append((name, np.vstack([image, caption(image.shape[1], f"{name}  {residual}")])))
        self.index += 1


def write_page(out: Path, summary: dict, frames_csv: str, overlays: Overlays, lines: list[str]) -> None:
    if overlays.drawn:
        write_gif(out / "overlay.gif", [image for _, image in overlays.drawn])
    stills = overlays.drawn[::max(1, len(overlays.drawn) // STILLS)][:STILLS]
    (out / "overlays").mkdir(exist_ok=True)
    for k, (_, image) in enumerate(stills):
        write_png(out / "overlays" / f"{k:02d}.png", image[..., ::-1])
    rows = [r.split(",") for r in frames_csv.strip().splitlines()]
    table = "".join("<tr>" + "".join(f"<{'th' if i == 0 else 'td'}>{html.escape(c)}</{'th' if i == 0 else 'td'}>"
                                      for c in row) + "</tr>" for i, row in enumerate(rows))
    pictures = "".join(f'<img src="overlays/{k:02d}.png" alt="frame {html.escape(n)}">' for k, (n, _) in enumerate(stills))
    body = "".join(f"<p>{html.escape(line)}</p>" for line in lines)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>Calibration: {html.escape(summary['verdict'])}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}} img{{margin:2px;max-width:32%}}
table{{border-collapse:collapse;font-size:12px}} td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}</style>
</head><body><h1>Camera-to-base calibration</h1>{body}
<p>Magenta: the robot's outline at the final calibration (URDF meshes placed by the joint states). A good
calibration lies on the robot's edges in every frame.</p>
{'<img src="overlay.gif" alt="the recording with the fitted outline" style="max-width:60%">' if overlays.drawn else ''}
<div>{pictures}</div><h2>Per frame</h2><p>outline: mean distance of the fitted outline to the robot's mask
(the estimator's own segmentation, or the given mask's prior); depth: median |sensor - model| over the robot's
pixels that agree; estimated: the frame had an estimate; key_frame: in the estimator's memory at the end.</p>
<table>{table}</table></body></html>"""
    write_atomic(out / "report.html", page.encode())
