"""Contact sheets: a rendered data set and its templates at a glance, drawn with OpenCV (no bpy).

The data-set sheet has one tile per configuration: a few frames spread over its segments, each the RGB
with the ground-truth mask outlined above the depth as a colour map, and a caption (segment, frame,
visible fraction). The template sheet of an end-effector shows in-plane rotation 0 of every view.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from kernel.bop import read_frame
from kernel.dataset import Dataset
from kernel.drawing import BACKGROUND, GT_COLOUR, caption, draw_outline, side_by_side
from kernel.errors import UserError
from kernel.files import write_png
from kernel.template_set import INDEX, read_index, read_template

PAD = 4

MAX_FRAMES, MAX_WIDTH = 16, 640  # a sheet is for looking at: 18 configurations x 16 frames x 640x480 is ~270 MB


@dataclass
class Tile:
    config: str
    scene_ids: list[int]
    box: tuple[int, int, int, int]  # x, y, w, h in the sheet


@dataclass
class Sheet:
    image: np.ndarray  # (H, W, 3) uint8 RGB
    tiles: list[Tile]


def depth_colours(depth: np.ndarray) -> np.ndarray:
    """Turbo colour map stretched over the frame's valid depths (near = blue); no depth is black."""
    valid = depth > 0
    out = np.zeros((*depth.shape, 3), np.uint8)
    if valid.any():
        near, far = np.percentile(depth[valid], (1, 99))
        scaled = np.clip((depth - near) / max(far - near, 1e-6), 0, 1)
        coloured = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
        out[valid] = coloured[valid]
    return out


def resize(image: np.ndarray, width: int) -> np.ndarray:
    height = max(1, round(image.shape[0] * width / image.shape[1]))
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def grid(images: list[np.ndarray], columns: int) -> tuple[np.ndarray, list[tuple[int, int, int, int]]]:
    """Images on a dark canvas, row by row, each in a cell of the largest size; returns the boxes too."""
    cell_h = max(im.shape[0] for im in images) + PAD
    cell_w = max(im.shape[1] for im in images) + PAD
    columns = max(1, min(columns, len(images)))
    rows = -(-len(images) // columns)
    canvas = np.full((rows * cell_h + PAD, columns * cell_w + PAD, 3), BACKGROUND, np.uint8)
    boxes = []
    for i, im in enumerate(images):
        x, y = PAD + (i % columns) * cell_w, PAD + (i // columns) * cell_h
        canvas[y:y + im.shape[0], x:x + im.shape[1]] = im
        boxes.append((x, y, im.shape[1], im.shape[0]))
    return canvas, boxes


def frame_panel(scene_dir: Path, scene_id: int, im_id: int, width: int) -> np.ndarray:
    frame = read_frame(scene_dir, im_id)
    rgb = resize(frame.rgb, width)
    mask = resize(frame.mask.astype(np.float32), width) > 0.5
    visible = frame.mask_visib.sum() / max(frame.mask.sum(), 1)
    return np.vstack([draw_outline(rgb, mask, GT_COLOUR), resize(depth_colours(frame.depth), width),
                      caption(width, f"seg {scene_id} f{im_id} vis {visible:.2f}")])


def scenes_by_config(root: Path) -> dict[str, list[tuple[int, Path, list[int]]]]:
    """(scene id, folder, frame ids) of every scene of the data set's split, grouped by configuration."""
    dataset = Dataset(Path(root))
    if not dataset.split_dir.is_dir():
        raise UserError(f"{root}: no {dataset.split}/ folder; give the root of a data set written by "
                        "python -m syneepose render --out DIR")
    groups = defaultdict(list)
    for scene in dataset.scenes():
        groups[scene.config].append((scene.scene_id, scene.path, scene.im_ids))
    if not groups:
        raise UserError(f"{dataset.split_dir}: no scenes; render some with python -m syneepose render --out {root}")
    return dict(sorted(groups.items()))


def contact_sheet(root: Path, frames: int = 4, width: int = 160, columns: int = 3) -> Sheet:
    """One tile per configuration with `frames` frames spread evenly over its segments' frames."""
    if not 1 <= frames <= MAX_FRAMES:
        raise UserError(f"--frames {frames}: must lie in 1..{MAX_FRAMES} frames per configuration")
    if not 32 <= width <= MAX_WIDTH:
        raise UserError(f"--width {width}: must lie in 32..{MAX_WIDTH} pixels per frame")
    tiles, images = [], []
    for config, scenes in scenes_by_config(root).items():
        pairs = [(scene_id, scene_dir, im_id) for scene_id, scene_dir, im_ids in scenes for im_id in im_ids]
        picked = sorted(set(np.linspace(0, len(pairs) - 1, min(frames, len(pairs))).round().astype(int)))
        panels = side_by_side([frame_panel(pairs[i][1], pairs[i][0], pairs[i][2], width) for i in picked])
        n = len(scenes)
        images.append(np.vstack([caption(panels.shape[1], f"{config}  ({n} segment{'s' * (n > 1)})"), panels]))
        tiles.append(Tile(config, [scene_id for scene_id, _, _ in scenes], (0, 0, 0, 0)))
    image, boxes = grid(images, columns)
    for tile, box in zip(tiles, boxes):
        tile.box = box
    return Sheet(image, tiles)


def template_sheet(folder: Path, columns: int = 5) -> np.ndarray:
    """In-plane rotation 0 of every view of one template set, mask outlined, captioned with the view."""
    index = read_index(folder)
    ids = sorted((rec["view"], int(key)) for key, rec in index.items() if rec["inplane"] == 0)
    panels = []
    for view, template_id in ids:
        template = read_template(folder, template_id, index)
        rgb = draw_outline(template.rgb.copy(), template.mask, GT_COLOUR)
        panels.append(np.vstack([rgb, caption(rgb.shape[1], f"view {view} (#{template_id})")]))
    if not panels:
        raise UserError(f"{folder}: templates.json lists no template at in-plane rotation 0; render the set again")
    image, _ = grid(panels, columns)
    return np.vstack([caption(image.shape[1], Path(folder).name), image])


def write_sheets(root: Path, out: Path, frames: int = 4, width: int = 160) -> tuple[Sheet, list[Path]]:
    """The data-set sheet at `out` and one template sheet per set beside it (`<stem>-templates-<set>.png`)."""
    root, out = Path(root), Path(out)
    sheet = contact_sheet(root, frames, width)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        written = [out]
        write_png(out, cv2.cvtColor(sheet.image, cv2.COLOR_RGB2BGR))
        template_root = Dataset(root).templates_dir
        sets = sorted(p for p in template_root.iterdir() if (p / INDEX).is_file()) if template_root.is_dir() else []
        for folder in sets:
            written.append(out.with_name(f"{out.stem}-templates-{folder.name}.png"))
            write_png(written[-1], cv2.cvtColor(template_sheet(folder), cv2.COLOR_RGB2BGR))
    except OSError as exc:
        raise UserError(f"cannot write {exc.filename or out}: {exc.strerror}; give a writable --out") from exc
    return sheet, written
