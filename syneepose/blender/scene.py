"""Build and render a SynEEPose segment in Blender (Cycles).

One view layer, `main`: RGB, z-depth and object index. Depth and object index come from the pixel-centre
ray, so they agree with each other and with OpenCV. The end-effector's occlusion-free silhouette (BOP's
`mask`) is its rigid model rasterised (segment.py), no longer rendered by a second layer.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import bpy
import numpy as np
import trimesh

from kernel.errors import UserError
from syneepose.blender.exr import read_passes
from syneepose.colour import srgb_to_linear
from syneepose.devices import GPU_BACKENDS, gpu_backend
from syneepose.preset import DEFAULT_PREFILTER
from syneepose.robots.model import RobotModel
from syneepose.robots.robot import arm_links
from syneepose.scene.marker import MarkerBoard
from syneepose.scene.spec import Distractor, Light, Occluder, Plane, Surface

PASS_EE, PASS_BOARD = 1, 3
PASS_LINK0 = 16  # arm link k (of RobotObjects.arm_links) renders object index PASS_LINK0 + k
MAIN = "main"
BLENDER_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def reset(width: int, height: int, samples: int, denoise: bool = False, max_bounces: int = 12,
          world_color=(0.05, 0.05, 0.05), world_strength: float = 1.0, transparent: bool = False,
          device: str = "cpu", threads: int = 0, prefilter: str = DEFAULT_PREFILTER) -> None:
    """Empty Cycles scene; `transparent` renders the background black (templates); `threads` 0: all cores;
    `prefilter`: how the denoiser cleans its albedo and normal passes (preset.PREFILTERS)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "GPU" if device == "gpu" and _enable_gpu() else "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = denoise
    scene.cycles.denoising_prefilter = prefilter.upper()
    scene.cycles.max_bounces = max_bounces
    scene.cycles.seed = 0
    scene.render.threads_mode = "FIXED" if threads else "AUTO"
    scene.render.threads = max(threads, 1)
    scene.render.film_transparent = transparent
    # Off: with persistent data Cycles updates the scene between frames and a run's frames 1+ land on one
    # of two RGB outputs (66% of pixels, up to 75 levels apart, ur5e+panda_hand at mini settings); off, runs
    # are byte-identical at the same per-frame cost (issue 14; docs/syneepose.md, "Determinism")
    scene.render.use_persistent_data = False
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.dither_intensity = 0.0
    scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    scene.render.image_settings.color_depth = "32"
    for name in ("robot", "ee", "backdrop", "board"):
        scene.collection.children.link(bpy.data.collections.new(name))
    main = scene.view_layers[0]
    main.name = MAIN
    main.use_pass_z = main.use_pass_object_index = True
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (*world_color, 1.0)
    background.inputs["Strength"].default_value = world_strength


def gpu_devices() -> dict[str, list[str]]:
    """The GPUs Cycles lists under each backend it was built with (backend -> device names)."""
    prefs = bpy.context.preferences.addons["cycles"].preferences
    found = {}
    for backend in GPU_BACKENDS:
        try:
            prefs.compute_device_type = backend
        except TypeError:  # not built into this Cycles
            continue
        prefs.get_devices()
        found[backend] = [d.name for d in prefs.devices if d.type != "CPU"]
    return found


def _enable_gpu() -> bool:
    """Turn on every GPU of the first backend that has one (syneepose/devices.py); refuse clearly when none."""
    backend = gpu_backend(gpu_devices())
    prefs = bpy.context.preferences.addons["cycles"].preferences
    prefs.compute_device_type = backend
    prefs.get_devices()
    for d in prefs.devices:
        d.use = d.type != "CPU"
    return True


def set_camera(K: np.ndarray, width: int, height: int, T_base_cam: np.ndarray) -> None:
    """OpenCV intrinsics -> Blender camera (pixel centres at integers; checked to 0.01 px)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    data = bpy.data.cameras.new("camera")
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = 36.0
    data.lens = fx * 36.0 / width
    data.shift_x = ((width - 1) / 2 - cx) / width
    data.shift_y = (cy - (height - 1) / 2) / width * (fx / fy)
    data.clip_start, data.clip_end = 0.01, 100.0
    scene = bpy.context.scene
    scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = (1.0, fx / fy) if fx >= fy else (fy / fx, 1.0)
    cam = bpy.data.objects.new("camera", data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    move_camera(T_base_cam)


def move_camera(T_base_cam: np.ndarray) -> None:
    bpy.context.scene.camera.matrix_world = (T_base_cam @ BLENDER_FROM_OPENCV).T.tolist()


def _mesh(name: str, vertices: np.ndarray, faces: np.ndarray, smooth_angle: float | None = 0.6):
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(vertices))
    me.vertices.foreach_set("co", np.asarray(vertices, dtype=np.float32).ravel())
    me.loops.add(3 * len(faces))
    me.loops.foreach_set("vertex_index", np.asarray(faces, dtype=np.int32).ravel())
    me.polygons.add(len(faces))
    me.polygons.foreach_set("loop_start", np.arange(0, 3 * len(faces), 3, dtype=np.int32))
    me.update()
    me.validate()
    if smooth_angle is not None:
        me.shade_smooth()
        me.set_sharp_from_angle(angle=smooth_angle)
    return me


def _object(name: str, mesh, material, collection: str, pass_index: int = 0):
    ob = bpy.data.objects.new(name, mesh)
    ob.data.materials.append(material)
    ob.pass_index = pass_index
    bpy.data.collections[collection].objects.link(ob)
    return ob


def _principled(name: str):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    return mat, mat.node_tree.nodes["Principled BSDF"]


def rgba_material(name: str, rgba, roughness: float = 0.4, metallic: float = 0.0):
    mat, bsdf = _principled(name)
    bsdf.inputs["Base Color"].default_value = (*srgb_to_linear(rgba[:3]), 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    return mat


TEXTURE_NODES = {"noise": ("ShaderNodeTexNoise", "Fac"), "voronoi": ("ShaderNodeTexVoronoi", "Distance"),
                 "wave": ("ShaderNodeTexWave", "Fac"), "brick": ("ShaderNodeTexBrick", "Fac"),
                 "checker": ("ShaderNodeTexChecker", "Fac")}


def surface_material(name: str, surface: Surface):
    mat, bsdf = _principled(name)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf.inputs["Roughness"].default_value = surface.roughness
    if surface.image:
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = bpy.data.images.load(surface.image)
        links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        return mat
    if surface.kind == "plain":
        bsdf.inputs["Base Color"].default_value = (*surface.color_a, 1.0)
        return mat
    coords = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (surface.scale,) * 3
    node_type, output = TEXTURE_NODES[surface.kind]
    tex = nodes.new(node_type)
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (*surface.color_a, 1.0)
    ramp.color_ramp.elements[1].color = (*surface.color_b, 1.0)
    links.new(coords.outputs["Object"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    links.new(tex.outputs[output], ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


class RobotObjects:
    """One Blender object per URDF visual; `pose` places them from FK link poses."""

    def __init__(self, model: RobotModel, urdf_dir: Path, ee_links: set[str]):
        self.items = []
        self.arm_links = arm_links(model, ee_links)
        meshes, materials = {}, {}
        for link in model.links:
            is_ee = link.name in ee_links
            for k, visual in enumerate(link.visuals):
                if visual.mesh not in meshes:
                    tm = trimesh.load(str(Path(urdf_dir) / visual.mesh), force="mesh", process=False)
                    meshes[visual.mesh] = _mesh(Path(visual.mesh).stem, tm.vertices, tm.faces)
                key = tuple(np.round(visual.rgba, 4))
                if key not in materials:
                    materials[key] = rgba_material(f"robot_{len(materials)}", visual.rgba)
                ob = _object(f"{link.name}_{k}", meshes[visual.mesh], materials[key], "ee" if is_ee else "robot",
                             PASS_EE if is_ee else PASS_LINK0 + self.arm_links.index(link.name))
                self.items.append((link.name, visual.origin, ob))

    def link_ids(self, index: np.ndarray) -> np.ndarray:
        """The object-index pass as robot part ids: arm link k -> k + 1, the end-effector -> len(arm_links) + 1."""
        ids = np.zeros(index.shape, dtype=np.uint8)
        arm = (index >= PASS_LINK0) & (index < PASS_LINK0 + len(self.arm_links))
        ids[arm] = index[arm] - PASS_LINK0 + 1
        ids[index == PASS_EE] = len(self.arm_links) + 1
        return ids

    def pose(self, T_base_link: dict[str, np.ndarray]) -> None:
        for link, origin, ob in self.items:
            ob.matrix_world = (T_base_link[link] @ origin).T.tolist()


def add_lights(lights: list[Light]) -> None:
    for i, spec in enumerate(lights):
        data = bpy.data.lights.new(f"light{i}", spec.kind)
        data.color = spec.color
        data.energy = spec.energy
        if spec.kind == "AREA":
            data.size = spec.size
        elif spec.kind == "POINT":
            data.shadow_soft_size = spec.size
        else:
            data.angle = spec.size
        ob = bpy.data.objects.new(f"light{i}", data)
        ob.matrix_world = spec.T_base_light.T.tolist()
        bpy.context.scene.collection.objects.link(ob)


def add_planes(planes: list[Plane]) -> None:
    for i, plane in enumerate(planes):
        w, h = plane.size
        v = np.array([[-w / 2, -h / 2, 0], [w / 2, -h / 2, 0], [w / 2, h / 2, 0], [-w / 2, h / 2, 0]])
        ob = _object(f"plane{i}", _mesh(f"plane{i}", v, np.array([[0, 1, 2], [0, 2, 3]]), None),
                     surface_material(f"plane{i}", plane.surface), "backdrop")
        ob.matrix_world = plane.T_base_plane.T.tolist()


DISTRACTOR_MESHES = {
    "cube": lambda d: trimesh.creation.box(extents=(d.size,) * 3),
    "sphere": lambda d: trimesh.creation.icosphere(subdivisions=3, radius=d.size / 2),
    "cylinder": lambda d: trimesh.creation.cylinder(radius=d.size / 3, height=d.size, sections=48),
    "torus": lambda d: trimesh.creation.torus(major_radius=d.size / 2, minor_radius=d.size / 6),
    "capsule": lambda d: trimesh.creation.capsule(height=d.size, radius=d.radius, count=[48, 24]),
}


def _shape(name: str, d: Distractor | Occluder):
    tm = DISTRACTOR_MESHES[d.kind](d)
    return _object(name, _mesh(name, tm.vertices, tm.faces), surface_material(name, d.surface), "backdrop")


def add_distractors(distractors: list[Distractor]) -> None:
    for i, d in enumerate(distractors):
        _shape(f"distractor{i}", d).matrix_world = d.T_base_obj.T.tolist()


def add_occluders(occluders: list[Occluder]) -> list:
    """The moving objects' Blender objects, for the caller to pose every frame (`T_base_obj[i]`)."""
    return [_shape(f"occluder{i}", o) for i, o in enumerate(occluders)]


def add_board(board: MarkerBoard, px_per_m: float = 4000.0):
    """The ChArUco board as one object: its printed face (UV-mapped image, white 0.85, black 0.03) and a
    grey back 2 mm behind it; the caller poses it every frame (`T_base_ee @ board.T_ee_board`)."""
    printed = board.image(px_per_m)
    image = bpy.data.images.new("charuco", printed.shape[1], printed.shape[0])
    grey = 0.03 + 0.82 * np.flipud(printed).astype(np.float32) / 255.0  # Blender stores rows bottom-up
    image.pixels.foreach_set(_rgba(grey))
    face, face_bsdf = _principled("board_face")
    tex = face.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    face.node_tree.links.new(tex.outputs["Color"], face_bsdf.inputs["Base Color"])
    face_bsdf.inputs["Roughness"].default_value = 0.7
    back = rgba_material("board_back", (0.3, 0.3, 0.3, 1.0), roughness=0.6)

    w, h = board.size
    m = board.margin
    xy = np.array([[-m, -m], [w + m, -m], [w + m, h + m], [-m, h + m]])
    vertices = np.concatenate([np.c_[xy, np.zeros(4)], np.c_[xy, np.full(4, 0.002)]])
    faces = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]])
    me = _mesh("board", vertices, faces, None)
    uv = np.c_[(xy[:, 0] + m) / (w + 2 * m), 1.0 - (xy[:, 1] + m) / (h + 2 * m)]
    loop_uv = np.concatenate([uv, uv])[faces.ravel()]
    me.uv_layers.new(name="UVMap").data.foreach_set("uv", loop_uv.astype(np.float32).ravel())
    ob = _object("board", me, face, "board", PASS_BOARD)
    ob.data.materials.append(back)
    me.polygons.foreach_set("material_index", np.array([0, 0, 1, 1], dtype=np.int32))
    return ob


def _rgba(grey: np.ndarray) -> np.ndarray:
    out = np.ones((*grey.shape, 4), np.float32)
    out[..., :3] = grey[..., None]
    return out.ravel()


LAYER_PASSES = {MAIN: ("Combined", "Depth", "Object Index")}


def render(workdir: Path | None = None) -> dict[str, np.ndarray]:
    """Render the current frame; returns linear RGB and the main layer's depth and object index (H, W)."""
    fd, path = tempfile.mkstemp(suffix=".exr", dir=workdir)
    os.close(fd)
    try:
        bpy.context.scene.render.filepath = path
        bpy.ops.render.render(write_still=True)
        try:
            passes = read_passes(Path(path))
        except (OSError, RuntimeError, ValueError):  # OpenEXR on a file cut short
            passes = {}
    finally:
        os.unlink(path)
    layers = [layer.name for layer in bpy.context.scene.view_layers if layer.use]
    missing = [f"{layer}.{name}" for layer in layers for name in LAYER_PASSES[layer] if f"{layer}.{name}" not in passes]
    if missing:
        free_mb = shutil.disk_usage(Path(path).parent).free / 2**20
        raise UserError(f"Blender's render came back without {', '.join(missing)} ({free_mb:.0f} MB free in "
                        f"{Path(path).parent}: a full disk cuts its EXR short); free space and run again")
    return {"rgb_linear": passes[f"{MAIN}.Combined"][..., :3], "depth": passes[f"{MAIN}.Depth"],
            "index": np.rint(passes[f"{MAIN}.Object Index"]).astype(np.int32)}
