"""The IR half of the active-stereo sensor in Blender: two IR imagers on the RGB camera's x axis and a
spot light that projects the random-dot pattern (a texture looked up by the light's ray direction).

The IR images reuse the scene with its lights and world dimmed to the profile's `ambient` share and the
projector switched on; materials keep their visible reflectance (an approximation: real IR albedo
differs). The projector is hidden in the RGB render, as the RGB imager's IR-cut filter would have it.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

from kernel.transforms import make_T
from syneepose.blender import scene as bscene
from syneepose.blender.exr import read_passes
from syneepose.stereo import SensorProfile, dot_pattern, ir_to_gray


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
    """Renders the left/right IR pair for the current frame; the RGB set-up is restored afterwards."""

    def __init__(self, profile: SensorProfile, width: int, height: int, seed: int = 0):
        self.profile = profile
        self.rgb_size = (width, height)
        self.ir_size = profile.ir_size(width, height)
        self.K_ir = profile.ir_K(width, height)
        self.projector = _projector(profile, dot_pattern(profile, self.ir_size[0], seed))
        data = bpy.data.cameras.new("ir_camera")
        data.sensor_fit = "HORIZONTAL"
        data.sensor_width = 36.0
        data.lens = self.K_ir[0, 0] * 36.0 / self.ir_size[0]
        data.clip_start, data.clip_end = 0.01, 100.0
        self.camera = bpy.data.objects.new("ir_camera", data)
        bpy.context.scene.collection.objects.link(self.camera)
        self.T_irleft_projector = make_T(t=[profile.projector["offset"], 0.0, 0.0])

    def render_pair(self, T_base_rgb: np.ndarray, workdir: Path) -> tuple[np.ndarray, np.ndarray]:
        scene = bpy.context.scene
        T_base_left = T_base_rgb @ self.profile.T_rgb_irleft
        saved = self._ir_mode(T_base_left)
        try:
            images = []
            for T in (T_base_left, T_base_left @ self.profile.T_irleft_irright):
                self.camera.matrix_world = (T @ bscene.BLENDER_FROM_OPENCV).T.tolist()
                fd_path = Path(workdir) / f".ir{len(images)}.exr"
                scene.render.filepath = str(fd_path)
                bpy.ops.render.render(write_still=True)
                images.append(ir_to_gray(read_passes(fd_path)[f"{bscene.MAIN}.Combined"]))
                fd_path.unlink()
        finally:
            self._rgb_mode(saved)
        return images[0], images[1]

    def _ir_mode(self, T_base_left: np.ndarray) -> dict:
        scene = bpy.context.scene
        background = scene.world.node_tree.nodes["Background"].inputs["Strength"]
        lights = [ob for ob in scene.objects if ob.type == "LIGHT" and ob is not self.projector]
        saved = {"camera": scene.camera, "size": (scene.render.resolution_x, scene.render.resolution_y),
                 "aspect": (scene.render.pixel_aspect_x, scene.render.pixel_aspect_y),
                 "samples": scene.cycles.samples, "denoise": scene.cycles.use_denoising,
                 "world": background.default_value, "lights": [(ob, ob.data.energy) for ob in lights]}
        scene.camera = self.camera
        scene.render.resolution_x, scene.render.resolution_y = self.ir_size
        scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
        scene.cycles.samples = self.profile.ir_samples
        scene.cycles.use_denoising = False
        scene.view_layers[bscene.EE_ONLY].use = False
        background.default_value = saved["world"] * self.profile.ambient
        for ob, energy in saved["lights"]:
            ob.data.energy = energy * self.profile.ambient
        self.projector.matrix_world = (T_base_left @ self.T_irleft_projector @ bscene.BLENDER_FROM_OPENCV).T.tolist()
        self.projector.hide_render = False
        return saved

    def _rgb_mode(self, saved: dict) -> None:
        scene = bpy.context.scene
        scene.camera = saved["camera"]
        scene.render.resolution_x, scene.render.resolution_y = saved["size"]
        scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = saved["aspect"]
        scene.cycles.samples = saved["samples"]
        scene.cycles.use_denoising = saved["denoise"]
        scene.view_layers[bscene.EE_ONLY].use = True
        scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = saved["world"]
        for ob, energy in saved["lights"]:
            ob.data.energy = energy
        self.projector.hide_render = True
