"""The IR pair of the active-stereo sensor shaded from G-buffers instead of path-traced (issue 36).

Path-traced IR cost 8-12x an exact-depth frame. Here each IR imager's G-buffer (depth, world normal,
diffuse and glossy colour and roughness of one pixel-centre ray, rendered by syneepose/blender/stereo.py)
and a depth map seen from the projector (its shadow test) give each pixel's light in closed form:

- the projector's dots averaged over the pixel's footprint on the surface's tangent plane (a summed-area
  table of the pattern: a dot lands anywhere within a pixel and moves its intensity continuously, which the
  matcher's sub-pixel refinement needs), shadowed by what the projector does not see, returned by a
  Lambertian lobe (albedo / pi) and a GGX specular one weighted by Cycles' glossy colour - the projector
  sits between the imagers, so near-normal surfaces send the dots' specular reflection straight back, and a
  black gripper (the Robotiq 3-finger's parts have no diffuse albedo) shows dots by it alone;
- the scene's own lights and world at the profile's `ambient` share, unshadowed, Lambertian.

The imager then blurs, exposes both images alike (its auto-exposure brings the left image's 99th percentile
to `white_level`), adds shot noise (`full_well`), encodes with the sRGB curve as the path-traced pair is,
and adds read noise (`read_noise`); the noise parameters are calibrated against Intel's RMS model with
syneepose.blender.flat_patch. Inter-reflection, the lights' shadows and their specular reflection are left
out.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from kernel.camera import backproject, point_map, project
from kernel.transforms import inv_T
from syneepose.colour import LUMINANCE, linear_to_srgb

MAX_FOOTPRINT = 12.0  # pattern pixels a side: grazing pixels average at most this much of the pattern
SHADOW_TOLERANCE = (0.002, 0.01)  # metres + fraction of depth a point may lie behind the projector's depth map
EXPOSURE_PERCENTILE = 99.0


@dataclass
class GBuffer:
    """What one pixel-centre ray per pixel sees from an imager (OpenCV camera convention)."""

    depth: np.ndarray  # (h, w) metres along the optical axis; 0 where the ray hits nothing
    normal: np.ndarray  # (h, w, 3) unit normals in the base frame
    albedo: np.ndarray  # (h, w) luminance of the diffuse colour, linear
    gloss: np.ndarray  # (h, w) luminance of the glossy colour (the specular lobe's weight)
    roughness: np.ndarray  # (h, w) the surface's roughness (GGX alpha = roughness^2, as Blender's)
    K: np.ndarray
    T_base_cam: np.ndarray


class DotPattern:
    """The projector's pattern (square, uint8) spanning `hfov_deg` a side, with its summed-area table: built
    once per rig, read for every pixel's footprint."""

    def __init__(self, pattern: np.ndarray, hfov_deg: float):
        self.size = pattern.shape[0]
        self.scale = 0.5 / np.tan(np.deg2rad(hfov_deg) / 2)
        self.table = np.zeros((self.size + 1, self.size + 1))
        self.table[1:, 1:] = (pattern.astype(np.float64) / 255.0).cumsum(0).cumsum(1)

    def coords(self, points_proj: np.ndarray) -> np.ndarray:
        """(..., 2) pattern coordinates (column, row; pixel edges at integers) of points in the projector
        frame, as the path-traced spot light's texture lookup has them (syneepose/blender/stereo.py)."""
        z = np.maximum(points_proj[..., 2:3], 1e-9)
        return self.size * (0.5 + self.scale * points_proj[..., :2] / z)

    def box_mean(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Mean pattern value over axis-aligned boxes (..., 2) in pattern coordinates: the summed-area
        table read bilinearly, which is exact for a piecewise-constant image."""
        lo, hi = np.clip(lo, 0, self.size), np.clip(hi, 0, self.size)
        area = np.prod(hi - lo, -1)
        total = (self._integral(hi[..., 0], hi[..., 1]) - self._integral(lo[..., 0], hi[..., 1])
                 - self._integral(hi[..., 0], lo[..., 1]) + self._integral(lo[..., 0], lo[..., 1]))
        return np.where(area > 1e-9, total / np.maximum(area, 1e-9), 0.0)

    def _integral(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x0 = np.minimum(np.floor(x).astype(int), self.size - 1)
        y0 = np.minimum(np.floor(y).astype(int), self.size - 1)
        fx, fy = x - x0, y - y0
        t = self.table
        return ((1 - fx) * (1 - fy) * t[y0, x0] + fx * (1 - fy) * t[y0, x0 + 1] + (1 - fx) * fy * t[y0 + 1, x0]
                + fx * fy * t[y0 + 1, x0 + 1])


@dataclass
class Projector:
    """The dot projector at one frame: its pose, pattern, radiant intensity (W/sr) and what it sees (a depth
    map with its own intrinsics, for the shadow test)."""

    T_base_proj: np.ndarray
    pattern: DotPattern
    intensity: float
    shadow_depth: np.ndarray
    shadow_K: np.ndarray


@dataclass
class Lighting:
    """The scene's own light at the imagers, already scaled by the profile's `ambient` share: point-like
    lights (position, W/sr towards a surface, for area lights also their facing) and a uniform world."""

    positions: np.ndarray  # (n, 3) base frame, of the point and area lights
    intensities: np.ndarray  # (n,) W/sr (area lights: along their facing, falling with its cosine)
    facings: np.ndarray  # (n, 3) unit direction an area light shines along; zeros: isotropic
    suns: np.ndarray  # (m, 3) unit directions towards each sun
    sun_irradiance: np.ndarray  # (m,) W/m^2
    world_radiance: float  # W/(m^2 sr), seen from every direction

    @classmethod
    def of(cls, lights, world_color, world_strength: float, share: float) -> "Lighting":
        """From the segment's lights (syneepose.scene.spec.Light) and world, at the `share` the IR imagers see;
        radiant intensity as Cycles sets it: a point light of P W emits P / (4 pi) W/sr, an area light
        P / pi along its facing."""
        positions, intensities, facings, suns, sun_irradiance = [], [], [], [], []
        for light in lights:
            power = share * light.energy * float(np.dot(light.color, LUMINANCE))
            facing = -light.T_base_light[:3, 2]  # Blender lights shine along their local -z
            if light.kind == "SUN":
                suns.append(-facing)
                sun_irradiance.append(power)
                continue
            positions.append(light.T_base_light[:3, 3])
            intensities.append(power / np.pi if light.kind == "AREA" else power / (4 * np.pi))
            facings.append(facing if light.kind == "AREA" else np.zeros(3))
        return cls(np.reshape(positions, (-1, 3)), np.array(intensities), np.reshape(facings, (-1, 3)),
                   np.reshape(suns, (-1, 3)), np.array(sun_irradiance),
                   share * world_strength * float(np.dot(world_color, LUMINANCE)))

    def irradiance(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        out = np.zeros(points.shape[:-1])
        for position, intensity, facing in zip(self.positions, self.intensities, self.facings):
            to_light = position - points
            r2 = np.maximum(np.sum(to_light**2, -1), 1e-6)
            direction = to_light / np.sqrt(r2)[..., None]
            emitted = intensity * (np.maximum(-direction @ facing, 0.0) if facing.any() else 1.0)
            out += emitted * np.maximum(np.sum(normals * direction, -1), 0.0) / r2
        for direction, irradiance in zip(self.suns, self.sun_irradiance):
            out += irradiance * np.maximum(normals @ direction, 0.0)
        return out


def dot_share(g: GBuffer, projector: Projector, points_cam: np.ndarray) -> np.ndarray:
    """The mean of the pattern over each pixel's footprint: the pixel's four corner rays met with the tangent
    plane of its centre's surface (`points_cam`: the imager's point map), taken to the pattern, and the
    pattern averaged over their bounding box."""
    h, w = g.depth.shape
    T_proj_cam = inv_T(projector.T_base_proj) @ g.T_base_cam
    normals_cam = g.normal @ g.T_base_cam[:3, :3]
    offset = np.sum(normals_cam * points_cam, -1)
    pixels = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1)
    corners = []
    for du, dv in ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)):
        ray = backproject(pixels + (du, dv), np.ones((h, w)), g.K)
        facing = np.sum(normals_cam * ray, -1)
        t = np.where(np.abs(facing) > 1e-6, offset / np.where(np.abs(facing) > 1e-6, facing, 1.0), g.depth)
        t = np.clip(t, 0.5 * g.depth, 2.0 * g.depth)  # grazing: the footprint stays near the pixel's own depth
        corner = (ray * t[..., None]) @ T_proj_cam[:3, :3].T + T_proj_cam[:3, 3]
        corners.append(projector.pattern.coords(corner))
    corners = np.stack(corners)
    lo, hi = corners.min(0), corners.max(0)
    middle, half = (lo + hi) / 2, np.minimum((hi - lo) / 2, MAX_FOOTPRINT / 2)
    return projector.pattern.box_mean(middle - half, middle + half)


def projector_sees(projector: Projector, points: np.ndarray) -> np.ndarray:
    """Points the projector reaches: in front of it and not behind the surface its depth map holds there
    (the largest of the 2 x 2 map pixels around the point, so a shadow's edge does not flicker)."""
    T = inv_T(projector.T_base_proj)
    local = points @ T[:3, :3].T + T[:3, 3]
    z = local[..., 2]
    uv = project(local.reshape(-1, 3), projector.shadow_K, min_z=1e-6).reshape(*z.shape, 2)
    h, w = projector.shadow_depth.shape
    x0 = np.clip(np.floor(uv[..., 0]).astype(int), 0, w - 2)
    y0 = np.clip(np.floor(uv[..., 1]).astype(int), 0, h - 2)
    d = projector.shadow_depth
    d = np.where(d > 0, d, np.inf)
    nearest = np.maximum.reduce([d[y0, x0], d[y0, x0 + 1], d[y0 + 1, x0], d[y0 + 1, x0 + 1]])
    inside = (uv[..., 0] >= -0.5) & (uv[..., 0] <= w - 0.5) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= h - 0.5)
    return (z > 0) & (~inside | (z <= nearest * (1 + SHADOW_TOLERANCE[1]) + SHADOW_TOLERANCE[0]))


def ggx_specular(normal: np.ndarray, to_light: np.ndarray, to_eye: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """The GGX microfacet BRDF without its Fresnel factor, D G / (4 (n.l) (n.v)), with Smith's masking
    (Walter et al., "Microfacet models for refraction through rough surfaces", EGSR 2007); unit vectors."""
    alpha2 = np.maximum(roughness, 0.02) ** 4
    half = to_light + to_eye
    half /= np.maximum(np.linalg.norm(half, axis=-1, keepdims=True), 1e-9)
    nh = np.clip(np.sum(normal * half, -1), 0.0, 1.0)
    nl = np.clip(np.sum(normal * to_light, -1), 1e-3, 1.0)
    nv = np.clip(np.sum(normal * to_eye, -1), 1e-3, 1.0)
    d = alpha2 / (np.pi * (nh**2 * (alpha2 - 1) + 1) ** 2)

    def g1(x):
        return 2 * x / (x + np.sqrt(alpha2 + (1 - alpha2) * x**2))

    return d * g1(nl) * g1(nv) / (4 * nl * nv)


def radiance(g: GBuffer, projector: Projector, lighting: Lighting) -> np.ndarray:
    """Radiance (W / (m^2 sr), luminance) each pixel of the imager receives; where the ray hits nothing,
    the world's."""
    hit = g.depth > 0
    points_cam = point_map(g.depth, g.K)
    points = points_cam @ g.T_base_cam[:3, :3].T + g.T_base_cam[:3, 3]
    to_projector = projector.T_base_proj[:3, 3] - points
    r2 = np.maximum(np.sum(to_projector**2, -1), 1e-6)
    to_projector /= np.sqrt(r2)[..., None]
    cosine = np.maximum(np.sum(g.normal * to_projector, -1), 0.0)
    dots = projector.intensity * dot_share(g, projector, points_cam) * cosine / r2
    dots = np.where(projector_sees(projector, points), dots, 0.0)
    to_eye = g.T_base_cam[:3, 3] - points
    to_eye /= np.maximum(np.linalg.norm(to_eye, axis=-1, keepdims=True), 1e-9)
    specular = g.gloss * ggx_specular(g.normal, to_projector, to_eye, g.roughness)
    lit = (g.albedo / np.pi * (dots + lighting.irradiance(points, g.normal)) + specular * dots
           + g.albedo * lighting.world_radiance)
    return np.where(hit, lit, lighting.world_radiance)


def expose(left: np.ndarray, right: np.ndarray, psf_sigma: float, white_level: float, full_well: float,
           read_noise: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """8-bit IR images as the imager records them: the optics' blur (Gaussian, `psf_sigma` pixels), one
    exposure for both (the left image's 99th percentile at `white_level` of full scale), shot noise of
    `full_well` electrons at full scale, the sRGB tone curve the path-traced pair is encoded with
    (syneepose.stereo.ir_to_gray; it lifts a black gripper's faint dots as it lifts theirs), read noise (digital
    numbers, Gaussian), clipped and rounded."""
    if psf_sigma > 0:
        left, right = (cv2.GaussianBlur(image, (0, 0), psf_sigma) for image in (left, right))
    reference = np.percentile(left, EXPOSURE_PERCENTILE)
    gain = white_level / reference if reference > 0 else 0.0
    images = []
    for image in (left, right):
        electrons = rng.poisson(np.clip(image * gain, 0.0, None) * full_well)
        counts = 255.0 * linear_to_srgb(electrons / full_well) + rng.normal(0.0, read_noise, image.shape)
        images.append(np.round(np.clip(counts, 0, 255)).astype(np.uint8))
    return images[0], images[1]
