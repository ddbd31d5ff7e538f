"""What a scored scene was computed from, so that a rerun into the same `--out` never reuses a stale score.

A scene's fingerprint lists every input file: the scene's JSON records by content hash, every image its frames'
reader opens (RGB, depth and the depth folder read, masks, the robot's part masks, a stereo sensor's extras) by
size and modification time (as make and rsync judge files; hashing
every image of a 54,000-frame data set on each rerun would cost more than scoring it), the evaluation
model by hash, the metric's rule and the method's own inputs (e.g. FEEPE's template set) by size and
modification time. The evaluation model and the metric only score the estimates: when nothing else
changed, the stored estimates are scored again without running the method.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from kernel.dataset import Scene

SCORING = {"model_eval": "the evaluation model (models_eval/)",  # what only the scoring reads, never the method
           "metric": "the metric's query rule"}


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _stat(path: Path) -> list[int] | None:
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return [st.st_size, st.st_mtime_ns]


def files_stat(paths: list[Path]) -> dict[str, list[int] | None]:
    """Size and mtime of each file; a folder stands for every file below it (hidden ones excepted)."""
    out = {}
    for path in paths:
        path = Path(path)
        if path.is_dir():
            for f in sorted(p for p in path.rglob("*") if p.is_file() and not p.name.startswith(".")):
                out[str(f)] = _stat(f)
        else:
            out[str(path)] = _stat(path)
    return out


def scene_fingerprint(scene: Scene, depth_dir: str | None, model_sha256: str, method_inputs: list[Path],
                      metric: dict) -> dict:
    """Every file the run reads for the scene: what reading its frames opens (kernel's layout,
    `Scene.inputs`), the method's own inputs, and what scores it."""
    records, images = scene.inputs(depth_dir)
    return {"im_ids": list(scene.im_ids), "json": {name: _sha256(path) for name, path in records.items()},
            "images": {name: _stat(path) for name, path in images.items()}, "model_eval": model_sha256,
            "metric": metric, "method_inputs": files_stat(method_inputs)}


def differences(before: dict, now: dict) -> list[str]:
    """What changed between two fingerprints, in words (first few items of each kind)."""
    said = []
    if before.get("im_ids") != now["im_ids"]:
        said.append(f"frames {before.get('im_ids')} -> {now['im_ids']}")
    for kind, label in (("json", ""), ("images", ""), ("method_inputs", "method input ")):
        old, new = before.get(kind, {}), now[kind]
        changed = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
        if changed:
            more = f" and {len(changed) - 3} more" if len(changed) > 3 else ""
            said.append(f"{label}{', '.join(Path(c).name if kind == 'method_inputs' else c for c in changed[:3])}{more}")
    said.extend(label for key, label in SCORING.items() if before.get(key) != now[key])
    return said


def only_scoring_changed(before: dict, now: dict) -> bool:
    """True when what the method read is unchanged, so its stored estimates can simply be scored again."""
    return all(before.get(k) == now[k] for k in now if k not in SCORING)


def read_fingerprint(path: Path) -> dict | None:
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
