"""`python -m syneepose assets`: sources -> part URDFs -> assembled URDFs -> BOP end-effector models ->
their resampled evaluation models (`models_eval/`).

Idempotent: each output folder carries a `.build.json` with the hash of what produced it (catalogue
entry, source version, converter code); a run whose hashes all match does no work. Each output folder
is built under a temporary name and renamed into place, so an interrupted run leaves nothing partial.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field
from importlib.metadata import version
from pathlib import Path

import trimesh
from filelock import FileLock

from kernel.dataset import MODELS_INFO, MODELS_NAMES, model_name
from kernel.errors import UserError
from syneepose import paths
from syneepose.robots import ee_models
from syneepose.robots.catalog import Catalog, Part, load_catalog
from syneepose.robots.model import read_urdf, write_urdf
from syneepose.robots.models_eval import build_models_eval
from syneepose.robots.parts import convert_part
from syneepose.robots.robot import assemble
from syneepose.robots.sources import ensure_source

STAMP = ".build.json"
_HERE = Path(__file__).parent
CONVERTER_CODE = ["model.py", "mjcf.py", "urdf_source.py", "parts.py", "../../kernel/transforms.py"]
ASSEMBLY_CODE = ["robot.py"]
MODEL_CODE = ["ee_models.py", "symmetry.py"]
MODEL_EVAL_CODE = ["models_eval.py", "../blender/remesh.py"]


def _code_hash(files) -> str:
    h = hashlib.sha256()
    for f in files:
        h.update((_HERE / f).read_bytes())
    return h.hexdigest()


def _hash(*items) -> str:
    return hashlib.sha256(json.dumps(items, sort_keys=True, default=str).encode()).hexdigest()[:20]


def _read_stamp(folder: Path) -> dict:
    try:
        return json.loads((folder / STAMP).read_text())
    except (OSError, ValueError):
        return {}


def _swap_in(tmp: Path, final: Path) -> None:
    """Replace `final` by the finished `tmp` folder without a moment where a half folder is visible."""
    old = None
    if final.exists():
        old = final.with_name(f".{final.name}.old{os.getpid()}")
        os.replace(final, old)
    os.replace(tmp, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _temp_dir(final: Path) -> Path:
    final.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{final.name}.tmp", dir=final.parent))


@dataclass
class BuildReport:
    parts: list[str] = field(default_factory=list)
    configs: list[str] = field(default_factory=list)
    models: list[str] = field(default_factory=list)
    models_eval: dict[str, int] = field(default_factory=dict)  # end-effector -> vertex count
    seconds: float = 0.0

    @property
    def did_work(self) -> bool:
        return bool(self.parts or self.configs or self.models or self.models_eval)


def part_recipe(catalog: Catalog, part: Part) -> str:
    return _hash(asdict(part), asdict(catalog.sources[part.source]), _code_hash(CONVERTER_CODE))


def build_part(catalog: Catalog, part: Part, out: Path) -> None:
    source = catalog.sources[part.source]
    root = ensure_source(source)
    model, meshes = convert_part(part, root)
    final = paths.part_dir(part.name, out)
    tmp = _temp_dir(final)
    try:
        (tmp / "meshes").mkdir()
        for rel, mesh in meshes.items():
            (tmp / rel).write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary"))
        write_urdf(model, tmp / f"{part.name}.urdf")
        for i, lic in enumerate(source.licence_files):
            shutil.copyfile(root / lic, tmp / f"LICENSE.{source.name}{'' if i == 0 else f'.{i}'}")
        (tmp / "SOURCE.txt").write_text(
            f"{part.name}: converted from {part.file} in {source.pip} (licence: {source.licence}).\n")
        (tmp / STAMP).write_text(json.dumps({"recipe": part_recipe(catalog, part)}))
        _swap_in(tmp, final)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def build_assets(out: Path | None = None, configs: list[str] | None = None, force: bool = False,
                 log=print) -> BuildReport:
    start = time.perf_counter()
    out = Path(out) if out is not None else paths.assets_dir()
    catalog = load_catalog()
    configs = configs if configs is not None else catalog.configurations
    pairs = [catalog.split(c) for c in configs]
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".write-probe{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise UserError(f"cannot write the assets folder {out}: {exc.strerror}; choose another with --out") from exc
    with FileLock(out / ".build.lock"):  # one builder at a time: a second one waits, then finds it built
        return _build(catalog, configs, pairs, out, force, log, start)


def _build(catalog: Catalog, configs: list[str], pairs: list, out: Path, force: bool, log, start: float) -> BuildReport:
    report = BuildReport()

    # Every end-effector is always built: models/ must hold all of them whatever subset is assembled.
    parts: dict[str, Part] = dict(catalog.end_effectors)
    for arm, _ in pairs:
        parts[arm.name] = arm
    recipes = {name: part_recipe(catalog, p) for name, p in parts.items()}
    for name, part in parts.items():
        if not force and _read_stamp(paths.part_dir(name, out)).get("recipe") == recipes[name]:
            continue
        t0 = time.perf_counter()
        build_part(catalog, part, out)
        report.parts.append(name)
        log(f"part {name}: {time.perf_counter() - t0:.1f} s")

    robots = out / "robots"
    stamps = _read_stamp(robots)
    assembly_code = _code_hash(ASSEMBLY_CODE)
    for config, (arm, ee) in zip(configs, pairs):
        recipe = _hash(recipes[arm.name], recipes[ee.name], assembly_code)
        urdf = paths.config_urdf(config, out)
        if not force and stamps.get(config) == recipe and urdf.is_file():
            continue
        model = assemble(config, read_urdf(paths.part_urdf(arm.name, out)),
                         read_urdf(paths.part_urdf(ee.name, out)), arm.flange_link)
        write_urdf(model, urdf)
        stamps[config] = recipe
        report.configs.append(config)
    if report.configs:
        ee_models.write_json(stamps, robots / STAMP)
        log(f"assembled {len(report.configs)} configurations")

    ees = sorted(catalog.end_effectors.values(), key=lambda e: e.obj_id)
    models = paths.models_dir(out)
    recipe = _hash([recipes[e.name] for e in ees], _code_hash(MODEL_CODE))
    if force or _read_stamp(models).get("recipe") != recipe:
        t0 = time.perf_counter()
        tmp = _temp_dir(models)
        try:
            infos = {}
            for ee in ees:
                mesh = ee_models.orient_outward(ee_models.load_ee_mesh(ee, paths.part_urdf(ee.name, out)))
                ee_models.write_ply_mm(mesh, tmp / model_name(ee.obj_id))
                infos[str(ee.obj_id)] = ee_models.model_info(mesh, ee)
                report.models.append(ee.name)
            ee_models.write_json(infos, tmp / MODELS_INFO)
            ee_models.write_json({str(e.obj_id): e.name for e in ees}, tmp / MODELS_NAMES)
            (tmp / STAMP).write_text(json.dumps({"recipe": recipe}))
            _swap_in(tmp, models)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        log(f"BOP models for {len(ees)} end-effectors: {time.perf_counter() - t0:.1f} s")

    models_eval = paths.models_eval_dir(out)
    eval_recipe = _hash(recipe, _code_hash(MODEL_EVAL_CODE), version("bpy"))
    if force or _read_stamp(models_eval).get("recipe") != eval_recipe:
        t0 = time.perf_counter()
        tmp = _temp_dir(models_eval)
        try:
            report.models_eval = build_models_eval(models, ees, tmp)
            (tmp / STAMP).write_text(json.dumps({"recipe": eval_recipe}))
            _swap_in(tmp, models_eval)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        log(f"BOP evaluation models (voxel remesh): {time.perf_counter() - t0:.1f} s, vertices "
            + ", ".join(f"{name} {n}" for name, n in report.models_eval.items()))
    report.seconds = time.perf_counter() - start
    return report
