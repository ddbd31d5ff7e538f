"""The IR half of the active-stereo sensor in Blender: two IR imagers on the RGB camera's x axis and the
random-dot projector between them.

`shaded` (the profile's default) renders G-buffers only - depth, normal, diffuse and glossy colour and
roughness of one pixel-centre ray per pixel from each imager (and depth from the projector for its shadow
test when the profile's `projector.shadow` is `rendered`; `splatted` takes it from the two imagers' G-buffers)
- and shades them in closed form (syneepose/ir_shading.py). `pathtraced` path-traces the IR pair: the scene with
its lights and world dimmed to the profile's `ambient` share and a spot light projecting the pattern (a
texture looked up by the light's ray direction), hidden in the RGB render as the RGB imager's IR-cut filter
would have it. Materials keep their visible reflectance either way (an approximation: real IR albedo
differs).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import bpy
import numpy as np

from kernel.transforms import make_T
from syneepose.blender import scene as bscene
from syneepose.blender.exr import read_passes
from syneepose.colour import LUMINANCE
from syneepose.ir_shading import DotPattern, GBuffer, Lighting, Projector, expose, projector_depth, radiance
from syneepose.stereo import SensorProfile, dot_pattern, ir_to_gray


ROUGHNESS_AOV = "roughness"


def _roughness_aov() -> None:
    """Each Principled material writes its roughness to an AOV of the main layer: no Cycles pass holds it,
    and the shaded IR's specular lobe needs it."""
    layer = bpy.context.scene.view_layers[bscene.MAIN]
    if ROUGHNESS_AOV not in layer.aovs:
        aov = layer.aovs.add()
        aov.name, aov.type = ROUGHNESS_AOV, "VALUE"
    for material in bpy.data.materials:
        nodes = material.node_tree.nodes if material.use_nodes else []
        bsdf = next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None)
        if bsdf is None or any(n.type == "OUTPUT_AOV" for n in nodes):
            continue
        out = nodes.new("ShaderNodeOutputAOV")
        out.aov_name = ROUGHNESS_AOV
        roughness = bsdf.inputs["Roughness"]
        if roughness.is_linked:
            material.node_tree.links.new(roughness.links[0].from_socket, out.inputs["Value"])
        else:
            out.inputs["Value"].default_value = roughness.default_value


def _projector(profile: SensorProfile, pattern: np.ndarray):
    """A spot light whose emission is the pattern, indexed by (x / -z, y / -z) of its ray direction."""
    light = bpy.data.lights.new("ir_projector", "SPOT")
    half = np.deg2rad(profile.projector["hfov_deg"]) / 2
    light.spot_size = float(2 * np.arctan(np.sqrt(2) * np.tan(half)))  # the cone covers the square's corners
    light.spot_blend = 0.0
    light.energy = float(profile.projector["power"])
    light.shadow_soft_size = 0.0
    light.use_nodes = True
    tree = light.node_tree
    nodes, links = tree.nodes, tree.links
    image = bpy.data.images.new("ir_dots", pattern.shape[1], pattern.shape[0])
    rgba = np.ones((*pattern.shape, 4), np.float32)
    rgba[..., :3] = (np.flipud(pattern).astype(np.float32) / 255.0)[..., None]
    image.pixels.foreach_set(rgba.ravel())
    coords = nodes.new("ShaderNodeTexCoord")
    split = nodes.new("ShaderNodeSeparateXYZ")
    links.new(coords.outputs["Normal"], split.inputs["Vector"])
    scale = 0.5 / np.tan(half)
    uv = []
    for axis in ("X", "Y"):
        ratio = nodes.new("ShaderNodeMath")
        ratio.operation = "DIVIDE"
        links.new(split.outputs[axis], ratio.inputs[0])
        links.new(split.outputs["Z"], ratio.inputs[1])
        shift = nodes.new("ShaderNodeMath")
        shift.operation = "MULTIPLY_ADD"  # 0.5 - scale * (axis / z): the light looks down -z
        links.new(ratio.outputs[0], shift.inputs[0])
        shift.inputs[1].default_value = -scale
        shift.inputs[2].default_value = 0.5
        uv.append(shift)
    join = nodes.new("ShaderNodeCombineXYZ")
    links.new(uv[0].outputs[0], join.inputs["X"])
    links.new(uv[1].outputs[0], join.inputs["Y"])
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Closest"
    tex.extension = "CLIP"
    links.new(join.outputs["Vector"], tex.inputs["Vector"])
    links.new(tex.outputs["Color"], nodes["Emission"].inputs["Color"])
    ob = bpy.data.objects.new("ir_projector", light)
    bpy.context.scene.collection.objects.link(ob)
    ob.hide_render = True
    return ob


class IrRig:
    """Renders the left/right IR pair for the current frame; the RGB set-up is restored afterwards.
    `lighting`: the scene's own light at the profile's ambient share (shaded IR only)."""

    def __init__(self, profile: SensorProfile, width: int, height: int, seed: int = 0,
                 lighting: Lighting | None = None):
        self.profile = profile
        self.seed = seed
        self.rgb_size = (width, height)
        self.ir_size = profile.ir_size(width, height)
        self.K_ir = profile.ir_K(width, height)
        pattern = dot_pattern(profile, self.ir_size[0], seed)
        self.lighting = lighting if lighting is not None else Lighting.of([], (0, 0, 0), 0.0, 0.0)
        self.projector, self.dots = None, None  # the path-traced pair's spot light, or the shaded pair's pattern
        if profile.ir_render == "pathtraced":
            self.projector = _projector(profile, pattern)
        else:
            self.dots = DotPattern(pattern, profile.projector["hfov_deg"])
            _roughness_aov()
        data = bpy.data.cameras.new("ir_camera")
        data.sensor_fit = "HORIZONTAL"
        data.sensor_width = 36.0
        data.clip_start, data.clip_end = 0.01, 100.0
        self.camera = bpy.data.objects.new("ir_camera", data)
        bpy.context.scene.collection.objects.link(self.camera)
        self.T_irleft_projector = make_T(t=[profile.projector["offset"], 0.0, 0.0])
        self.K_projector = profile.projector_K(width, height)

    def render_pair(self, T_base_rgb: np.ndarray, workdir: Path, frame: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """The 8-bit IR pair; `frame` seeds the shaded images' sensor noise (with the rig's seed)."""
        T_base_left = T_base_rgb @ self.profile.T_rgb_irleft
        T_base_right = T_base_left @ self.profile.T_irleft_irright
        if self.profile.ir_render == "pathtraced":
            return self._pathtraced(T_base_left, T_base_right, workdir)
        T_base_projector = T_base_left @ self.T_irleft_projector
        rendered = self.profile.projector["shadow"] == "rendered"
        saved = self._gbuffer_mode()
        try:
            views = [self._gbuffer(T, K, workdir) for T, K in (
                (T_base_left, self.K_ir), (T_base_right, self.K_ir),
                *([(T_base_projector, self.K_projector)] if rendered else []))]
        finally:
            self._restore(saved)
        left, right = views[:2]
        shadow = (views[2].depth if rendered else
                  projector_depth([left, right], T_base_projector, self.K_projector, self.ir_size[::-1]))
        projector = Projector(T_base_projector, self.dots, self.profile.projector["power"] / (4 * np.pi), shadow,
                              self.K_projector)
        imager = self.profile.imager
        with ThreadPoolExecutor(2) as pool:  # the compiled shading releases the GIL: one imager a core
            shaded = list(pool.map(lambda g: radiance(g, projector, self.lighting), (left, right)))
        return expose(*shaded, imager["psf_sigma"], imager["white_level"], imager["full_well"], imager["read_noise"],
                      np.random.default_rng([self.seed, frame]))

    def _aim(self, T_base_cam: np.ndarray, K: np.ndarray) -> None:
        """The IR camera at a pose, with K's focal length (its principal point is the image centre)."""
        self.camera.data.lens = K[0, 0] * 36.0 / self.ir_size[0]
        self.camera.matrix_world = (T_base_cam @ bscene.BLENDER_FROM_OPENCV).T.tolist()

    def _gbuffer(self, T_base_cam: np.ndarray, K: np.ndarray, workdir: Path) -> GBuffer:
        scene = bpy.context.scene
        self._aim(T_base_cam, K)
        path = Path(workdir) / ".gbuffer.exr"
        scene.render.filepath = str(path)
        bpy.ops.render.render(write_still=True)
        try:
            passes = read_passes(path)
        finally:
            path.unlink()
        depth = passes[f"{bscene.MAIN}.Depth"]
        albedo, gloss = (passes[f"{bscene.MAIN}.{name} Color"][..., :3] @ LUMINANCE for name in ("Diffuse", "Glossy"))
        return GBuffer(np.where(depth < 1e9, depth, 0.0), passes[f"{bscene.MAIN}.Normal"], albedo, gloss,
                       passes[f"{bscene.MAIN}.{ROUGHNESS_AOV}"], K, T_base_cam)

    def _gbuffer_mode(self) -> dict:
        """One pixel-centre ray per pixel, no light: what the G-buffer passes need and nothing else. The
        calls of a frame keep Cycles' session between them (persistent data: they differ only in the camera;
        their passes are byte-identical either way) and write their temporary EXR uncompressed, which saved
        about 0.3 s of a frame's three calls (docs/syneepose.md, "Sensor-like depth")."""
        scene = bpy.context.scene
        main = scene.view_layers[bscene.MAIN]
        background = scene.world.node_tree.nodes["Background"].inputs["Strength"]
        lights = [ob for ob in scene.objects if ob.type == "LIGHT"]
        saved = self._common_mode()
        saved.update({"bounces": scene.cycles.max_bounces, "filter": scene.cycles.filter_width,
                      "world": background.default_value, "hidden": [(ob, ob.hide_render) for ob in lights],
                      "passes": (main.use_pass_normal, main.use_pass_diffuse_color, main.use_pass_glossy_color),
                      "persistent": scene.render.use_persistent_data,
                      "codec": scene.render.image_settings.exr_codec})
        scene.render.use_persistent_data = True
        scene.render.image_settings.exr_codec = "NONE"
        scene.cycles.samples = 1
        scene.cycles.max_bounces = 0
        scene.cycles.filter_width = 0.01
        background.default_value = 0.0
        for ob in lights:
            ob.hide_render = True
        main.use_pass_normal = main.use_pass_diffuse_color = main.use_pass_glossy_color = True
        return saved

    def _pathtraced(self, T_base_left: np.ndarray, T_base_right: np.ndarray, workdir: Path):
        scene = bpy.context.scene
        saved = self._ir_mode(T_base_left)
        try:
            images = []
            for T in (T_base_left, T_base_right):
                self._aim(T, self.K_ir)
                fd_path = Path(workdir) / f".ir{len(images)}.exr"
                scene.render.filepath = str(fd_path)
                bpy.ops.render.render(write_still=True)
                images.append(ir_to_gray(read_passes(fd_path)[f"{bscene.MAIN}.Combined"]))
                fd_path.unlink()
        finally:
            self._restore(saved)
        return images[0], images[1]

    def _common_mode(self) -> dict:
        """The IR camera at the IR size, no denoiser; returns what it changed."""
        scene = bpy.context.scene
        saved = {"camera": scene.camera, "size": (scene.render.resolution_x, scene.render.resolution_y),
                 "aspect": (scene.render.pixel_aspect_x, scene.render.pixel_aspect_y),
                 "samples": scene.cycles.samples, "denoise": scene.cycles.use_denoising}
        scene.camera = self.camera
        scene.render.resolution_x, scene.render.resolution_y = self.ir_size
        scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
        scene.cycles.use_denoising = False
        return saved

    def _ir_mode(self, T_base_left: np.ndarray) -> dict:
        scene = bpy.context.scene
        background = scene.world.node_tree.nodes["Background"].inputs["Strength"]
        lights = [ob for ob in scene.objects if ob.type == "LIGHT" and ob is not self.projector]
        saved = self._common_mode()
        saved.update({"world": background.default_value, "lights": [(ob, ob.data.energy) for ob in lights]})
        scene.cycles.samples = self.profile.ir_samples
        background.default_value = saved["world"] * self.profile.ambient
        for ob, energy in saved["lights"]:
            ob.data.energy = energy * self.profile.ambient
        self.projector.matrix_world = (T_base_left @ self.T_irleft_projector @ bscene.BLENDER_FROM_OPENCV).T.tolist()
        self.projector.hide_render = False
        return saved

    def _restore(self, saved: dict) -> None:
        scene = bpy.context.scene
        main = scene.view_layers[bscene.MAIN]
        scene.camera = saved["camera"]
        scene.render.resolution_x, scene.render.resolution_y = saved["size"]
        scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = saved["aspect"]
        scene.cycles.samples = saved["samples"]
        scene.cycles.use_denoising = saved["denoise"]
        scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = saved["world"]
        for ob, energy in saved.get("lights", ()):
            ob.data.energy = energy
        for ob, hidden in saved.get("hidden", ()):
            ob.hide_render = hidden
        if "bounces" in saved:
            scene.cycles.max_bounces = saved["bounces"]
            scene.cycles.filter_width = saved["filter"]
            main.use_pass_normal, main.use_pass_diffuse_color, main.use_pass_glossy_color = saved["passes"]
            scene.render.use_persistent_data = saved["persistent"]
            scene.render.image_settings.exr_codec = saved["codec"]
        if self.projector is not None:
            self.projector.hide_render = True
