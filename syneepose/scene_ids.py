"""Stable scene ids: a data set numbers a scene once and keeps the number, so more configurations, more
segments or a shard never renumber a scene that exists.

A scene is segment `segment` of configuration `config` (its Key); dataset_info.json "scenes" records
id -> {"config", "segment"}, and a render into the data set numbers keys so:

1. a recorded key keeps its id;
2. a new key with segment < S takes its first-plan number, catalogue index x S + segment, unless the record gave it;
3. any other new key takes the next id above every id in use and every first-plan number, in key order.

S is the data set's segments per configuration when first planned (its settings "segments"), so a fresh data
set is numbered as before the record, and --robots subsets rendered one after another get one full run's ids.
Each segment's random stream is its first-plan number (`stream`), fixed by the key and S: a scene shows the
same whatever else the data set holds and whichever id it got. The number follows the catalogue's order, so a
catalogue that inserts a configuration before others starts a new data set.

A data set written before the record gets one by reading its ids as first-plan numbers, with S as recorded, or
else the only S under which every scene's scene_robot.json names the configuration its id stands for;
otherwise it is refused.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from kernel import bop, files
from kernel.errors import UserError
from syneepose.robots.catalog import load_catalog


@dataclass(frozen=True, order=True)
class Key:
    config: str
    segment: int


def stream(key: Key, segments: int, configurations: list[str]) -> int:
    """The key's first-plan number: its scene id before ids were recorded, and the number of its random
    stream (scene.sample.rng_for, the stereo projector's dots) for good."""
    return configurations.index(key.config) * segments + key.segment


def assign(recorded: dict[int, Key], keys: list[Key], segments: int, configurations: list[str],
           folders: set[int] = frozenset()) -> dict[int, Key]:
    """Every scene after this run by id: `recorded` kept, the new `keys` numbered by rules 2 and 3. Rule 3
    numbers above the `folders` too; rule 2 reuses one the record does not name, a folder a killed run left
    before its first frame, as a rerun did before the record."""
    ids = {key: i for i, key in recorded.items()}
    new = sorted({k for k in keys if k not in ids}, key=lambda k: (configurations.index(k.config), k.segment))
    used = set(recorded)
    later = []
    for key in new:
        first = stream(key, segments, configurations)
        if key.segment < segments and first not in used:
            ids[key] = first
            used.add(first)
        else:
            later.append(key)
    start = max([*used, *folders, len(configurations) * segments - 1]) + 1
    ids.update({key: start + n for n, key in enumerate(later)})
    return {i: key for key, i in sorted(ids.items(), key=lambda item: item[1])}


def fitting_segments(found: dict[int, str], configurations: list[str]) -> list[int]:
    """The segment counts S under which every found scene (id -> configuration) has a first-plan number as
    its id. Counts above the largest id + 1 fit only when they all do, so two fits or none is ambiguous."""
    index = {sid: configurations.index(config) for sid, config in found.items()}
    return [s for s in range(1, max(found) + 3) if all(i * s <= sid < (i + 1) * s for sid, i in index.items())]


def number(out: Path, keys: list[Key], segments: int) -> tuple[dict[int, Key], int]:
    """(Every scene of the data set in `out` after a run of `keys`, by id; its S). `segments`: the run's
    count, which becomes S of a data set that has none yet."""
    configurations = load_catalog().configurations
    folders = bop.scene_dirs(bop.split_dir(out))  # before the record: a concurrent shard records, then makes folders
    info = bop.read_dataset_info(out)
    s = _recorded_segments(info, out / bop.DATASET_INFO)
    if "scenes" in info:
        recorded = _recorded(info["scenes"], out / bop.DATASET_INFO)
    else:
        recorded, s = _first_plan(out, folders, s, configurations)
    s = s or segments
    return assign(recorded, keys, s, configurations, set(folders)), s


def _recorded(scenes, path: Path) -> dict[int, Key]:
    def bad(what: str) -> UserError:
        return UserError(f"{path}: \"scenes\" {what}; restore the file, or render into another --out")

    if not isinstance(scenes, dict):
        raise bad("is not an object of scene id -> {\"config\", \"segment\"}")
    recorded = {}
    for sid, entry in scenes.items():
        if not (sid.isdigit() and isinstance(entry, dict) and isinstance(entry.get("config"), str)
                and type(entry.get("segment")) is int and entry["segment"] >= 0):
            raise bad(f"{sid!r} is not a scene id -> {{\"config\", \"segment\"}}")
        recorded[int(sid)] = Key(entry["config"], entry["segment"])
    keys = list(recorded.values())
    twice = sorted(k for k in set(keys) if keys.count(k) > 1)
    if twice:
        raise bad(f"names {twice[0].config} segment {twice[0].segment} twice")
    return recorded


def _recorded_segments(record: dict, path: Path) -> int | None:
    """S as a dataset_info.json or scene_robot.json records it in its settings (None for none)."""
    settings = record.get("settings")
    value = settings.get("segments") if isinstance(settings, dict) else None
    if value is None or (type(value) is int and value >= 1):
        return value
    raise UserError(f"{path}: settings \"segments\" {value!r} is not a segment count; restore the file, or render "
                    "into another --out")


def _config(path: Path, record: dict, configurations: list[str]) -> str:
    config = f"{record.get('arm')}+{record.get('end_effector')}"
    if config not in configurations:
        raise UserError(f"{path}: configuration {config} is not in the robot catalogue; render into another --out")
    return config


def _only_fit(out: Path, found: dict[int, str], configurations: list[str]) -> int:
    fits = fitting_segments(found, configurations)
    if len(fits) == 1:
        return fits[0]
    counts = ", ".join(map(str, fits[:3])) + (" and up" if fits[-1:] == [max(found) + 2] else ", ..." * (len(fits) > 3))
    raise UserError(f"{out}: its scene ids are catalogue index x segments + segment for "
                    f"{f'segment counts {counts}' if fits else 'no segment count'}, and nothing records the one it was "
                    "rendered with (a data set from before recorded settings); render into another --out")


def _first_plan(out: Path, folders: dict[int, Path], segments: int | None,
                configurations: list[str]) -> tuple[dict[int, Key], int | None]:
    """The record of a data set from before it: each scene's id read as its first-plan number, with S as
    recorded (`segments` from dataset_info.json, else a scene's settings) or the only S that fits them all."""
    found = {}
    for sid, folder in folders.items():
        path = bop.record_paths(folder)["scene_robot"]
        if path.is_file():
            record = files.read_json(path)
            found[sid] = _config(path, record, configurations)
            segments = segments or _recorded_segments(record, path)
    if not found:
        return {}, segments
    segments = segments or _only_fit(out, found, configurations)
    recorded = {}
    for sid, config in found.items():
        segment = sid - configurations.index(config) * segments
        if not 0 <= segment < segments:
            raise UserError(f"{out}: scene {sid:06d} holds {config}, not what scene id {sid} stood for at {segments} "
                            "segments per configuration; render into another --out")
        recorded[sid] = Key(config, segment)
    return recorded, segments
