"""The IR pair of the active-stereo sensor shaded from G-buffers instead of path-traced (issue 36).

Path-traced IR cost 8-12x an exact-depth frame. Here each IR imager's G-buffer (depth, world normal,
diffuse and glossy colour and roughness of one pixel-centre ray, rendered by syneepose/blender/stereo.py)
and a depth map seen from the projector (its shadow test: splatted from the two G-buffers by
`projector_depth`, or rendered) give each pixel's light in closed form:

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
import numba
import numpy as np

from kernel.transforms import inv_T
from syneepose.colour import LUMINANCE, linear_to_srgb

MAX_FOOTPRINT = 12.0  # pattern pixels a side: grazing pixels average at most this much of the pattern
MAX_SPLAT = 12.0  # projector-map pixels a side: what a grazing imager pixel covers of the map at most
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


@numba.njit(cache=True, nogil=True)
def _integral(table: np.ndarray, size: int, x: float, y: float) -> float:
    """The summed-area table at (x, y), bilinear between its entries."""
    x0 = min(int(np.floor(x)), size - 1)
    y0 = min(int(np.floor(y)), size - 1)
    fx, fy = x - x0, y - y0
    return ((1 - fx) * (1 - fy) * table[y0, x0] + fx * (1 - fy) * table[y0, x0 + 1]
            + (1 - fx) * fy * table[y0 + 1, x0] + fx * fy * table[y0 + 1, x0 + 1])


@numba.njit(cache=True, nogil=True)
def box_mean(table: np.ndarray, size: int, lo_x: float, lo_y: float, hi_x: float, hi_y: float) -> float:
    """Mean pattern value over an axis-aligned box in pattern coordinates (DotPattern's `table` and `size`):
    the summed-area table read bilinearly, which is exact for a piecewise-constant image."""
    lo_x, lo_y = min(max(lo_x, 0.0), size), min(max(lo_y, 0.0), size)
    hi_x, hi_y = min(max(hi_x, 0.0), size), min(max(hi_y, 0.0), size)
    area = (hi_x - lo_x) * (hi_y - lo_y)
    if area <= 1e-9:
        return 0.0
    return (_integral(table, size, hi_x, hi_y) - _integral(table, size, lo_x, hi_y)
            - _integral(table, size, hi_x, lo_y) + _integral(table, size, lo_x, lo_y)) / area


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


def dot_share(g: GBuffer, projector: Projector, points_cam: np.ndarray) -> np.ndarray:
    """The mean of the pattern over each pixel's footprint (`points_cam`: the imager's point map); the
    per-pixel rule `radiance` applies, on its own."""
    T_proj_cam = inv_T(projector.T_base_proj) @ g.T_base_cam
    normals_cam = g.normal @ g.T_base_cam[:3, :3]
    pattern = projector.pattern
    out = np.empty(g.depth.shape)
    _footprint_means(*_f64(g.depth, normals_cam, points_cam, g.K, T_proj_cam), pattern.table, pattern.size,
                     pattern.scale, MAX_FOOTPRINT, out)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _moved(T, x, y, z):
    """A point moved by a 4 x 4 transform."""
    return (T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3], T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3],
            T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3])


@numba.njit(cache=True, nogil=True, inline="always")
def _rotated_back(R, x, y, z):
    """A direction moved by R's transpose (a base-frame normal into the camera frame, R = T_base_cam's)."""
    return (R[0, 0] * x + R[1, 0] * y + R[2, 0] * z, R[0, 1] * x + R[1, 1] * y + R[2, 1] * z,
            R[0, 2] * x + R[1, 2] * y + R[2, 2] * z)


@numba.njit(cache=True, nogil=True, inline="always")
def _corner(u, v, corner, d, nx, ny, nz, offset, K):
    """Where corner `corner` (0-3) of pixel (u, v)'s ray meets the tangent plane n . p = offset of its centre's
    surface (camera frame, depth d at the centre)."""
    rx = (u + (corner % 2 - 0.5) - K[0, 2]) / K[0, 0]
    ry = (v + (corner // 2 - 0.5) - K[1, 2]) / K[1, 1]
    facing = nx * rx + ny * ry + nz
    t = offset / facing if abs(facing) > 1e-6 else d
    t = min(max(t, 0.5 * d), 2.0 * d)  # grazing: the footprint stays near the pixel's own depth
    return rx * t, ry * t, t


@numba.njit(cache=True, nogil=True)
def _footprint_means(depth, normals, points, K, T, table, size, scale, max_footprint, out):
    for v in range(depth.shape[0]):
        for u in range(depth.shape[1]):
            out[v, u] = _footprint_mean(u, v, depth[v, u], normals[v, u, 0], normals[v, u, 1], normals[v, u, 2],
                                        points[v, u, 0], points[v, u, 1], points[v, u, 2], K, T, table, size,
                                        scale, max_footprint)


@numba.njit(cache=True, nogil=True)
def _footprint_mean(u, v, d, nx, ny, nz, x0, y0, z0, K, T, table, size, scale, max_footprint):
    """dot_share of pixel (u, v) (its camera point and normal): the pixel's four corner rays met with the
    tangent plane of its centre's surface, taken to the pattern, and the pattern averaged over their bounding
    box. A point in the projector frame lands at pattern column, row = size (0.5 + scale (x, y) / z) with
    pixel edges at integers, as the path-traced spot light's texture lookup has it
    (syneepose/blender/stereo.py)."""
    offset = nx * x0 + ny * y0 + nz * z0
    lo_x = lo_y = np.inf
    hi_x = hi_y = -np.inf
    for corner in range(4):
        x, y, z = _corner(u, v, corner, d, nx, ny, nz, offset, K)
        px, py, pz = _moved(T, x, y, z)
        pz = max(pz, 1e-9)
        cu, cv = size * (0.5 + scale * px / pz), size * (0.5 + scale * py / pz)
        lo_x, hi_x = min(lo_x, cu), max(hi_x, cu)
        lo_y, hi_y = min(lo_y, cv), max(hi_y, cv)
    mid_x, mid_y = (lo_x + hi_x) / 2, (lo_y + hi_y) / 2
    half_x = min((hi_x - lo_x) / 2, max_footprint / 2)
    half_y = min((hi_y - lo_y) / 2, max_footprint / 2)
    return box_mean(table, size, mid_x - half_x, mid_y - half_y, mid_x + half_x, mid_y + half_y)


def projector_sees(projector: Projector, points: np.ndarray) -> np.ndarray:
    """Points (base frame) the projector reaches; the per-pixel rule `radiance` applies, on its own."""
    out = np.empty(points.shape[:-1], np.bool_)
    flat = out.reshape(-1)
    _sees_all(*_f64(points.reshape(-1, 3), inv_T(projector.T_base_proj), projector.shadow_depth,
                    projector.shadow_K), flat)
    return out


@numba.njit(cache=True, nogil=True)
def _sees_all(points, T, shadow, K, out):
    for i in range(points.shape[0]):
        out[i] = _sees(points[i, 0], points[i, 1], points[i, 2], T, shadow, K)


@numba.njit(cache=True, nogil=True)
def _sees(x, y, z, T, shadow, K):
    """Whether the projector (T: base to projector frame) reaches a point: in front of it and not behind the
    surface its depth map holds there (the largest of the 2 x 2 map pixels around the point, so a shadow's
    edge does not flicker; no depth counts as infinitely far)."""
    lx, ly, lz = _moved(T, x, y, z)
    if lz <= 0:
        return False
    u = K[0, 0] * lx / max(lz, 1e-6) + K[0, 2]
    v = K[1, 1] * ly / max(lz, 1e-6) + K[1, 2]
    h, w = shadow.shape
    if u < -0.5 or u > w - 0.5 or v < -0.5 or v > h - 0.5:
        return True
    x0 = min(max(int(np.floor(u)), 0), w - 2)
    y0 = min(max(int(np.floor(v)), 0), h - 2)
    nearest = 0.0
    for dy in range(2):
        for dx in range(2):
            d = shadow[y0 + dy, x0 + dx]
            nearest = max(nearest, d if d > 0 else np.inf)
    return lz <= nearest * (1 + SHADOW_TOLERANCE[1]) + SHADOW_TOLERANCE[0]


def projector_depth(views: list[GBuffer], T_base_proj: np.ndarray, K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The depth map the projector's shadow test reads (metres along its axis, 0 where nothing is seen),
    splatted from the imagers' G-buffers instead of rendered from the projector: each imager pixel's footprint
    on its tangent plane (as `dot_share` takes it) covers the map's pixel centres inside its bounding box at
    its centre's depth, the nearest surface winning. The projector sits between the imagers, so what it sees
    of a convex surface one of them sees too; a surface neither sees (a slot open only to the middle, the
    strip beyond both imagers' fields of view) casts no shadow."""
    out = np.full(shape, np.inf)
    T_proj_base = inv_T(T_base_proj)
    for g in views:
        _splat(*_f64(g.depth, g.normal, g.T_base_cam, g.K, T_proj_base @ g.T_base_cam, K), MAX_SPLAT, out)
    return np.where(np.isfinite(out), out, 0.0)


@numba.njit(cache=True, nogil=True)
def _splat(depth, normals, T_base_cam, K, T, K_map, max_size, out):
    h, w = out.shape
    R = T_base_cam[:3, :3]
    for v in range(depth.shape[0]):
        for u in range(depth.shape[1]):
            d = depth[v, u]
            if d <= 0:
                continue
            nx, ny, nz = _rotated_back(R, normals[v, u, 0], normals[v, u, 1], normals[v, u, 2])
            cx, cy = (u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d
            px, py, z = _moved(T, cx, cy, d)
            if z <= 0:
                continue
            mu, mv = K_map[0, 0] * px / z + K_map[0, 2], K_map[1, 1] * py / z + K_map[1, 2]
            offset = nx * cx + ny * cy + nz * d
            lo_x = lo_y = np.inf
            hi_x = hi_y = -np.inf
            for corner in range(4):
                x, y, t = _corner(u, v, corner, d, nx, ny, nz, offset, K)
                px, py, pz = _moved(T, x, y, t)
                pz = max(pz, 1e-9)
                cu, cv = K_map[0, 0] * px / pz + K_map[0, 2], K_map[1, 1] * py / pz + K_map[1, 2]
                lo_x, hi_x = min(lo_x, cu), max(hi_x, cu)
                lo_y, hi_y = min(lo_y, cv), max(hi_y, cv)
            lo_x, hi_x = max(lo_x, mu - max_size / 2), min(hi_x, mu + max_size / 2)
            lo_y, hi_y = max(lo_y, mv - max_size / 2), min(hi_y, mv + max_size / 2)
            x0 = min(int(np.ceil(lo_x)), int(np.floor(mu + 0.5)))
            x1 = max(int(np.floor(hi_x)), int(np.floor(mu + 0.5)))
            y0 = min(int(np.ceil(lo_y)), int(np.floor(mv + 0.5)))
            y1 = max(int(np.floor(hi_y)), int(np.floor(mv + 0.5)))
            for y in range(max(y0, 0), min(y1, h - 1) + 1):
                for x in range(max(x0, 0), min(x1, w - 1) + 1):
                    if z < out[y, x]:
                        out[y, x] = z


@numba.njit(cache=True, nogil=True)
def ggx_specular(nx, ny, nz, lx, ly, lz, ex, ey, ez, roughness):
    """The GGX microfacet BRDF without its Fresnel factor, D G / (4 (n.l) (n.v)), with Smith's masking
    (Walter et al., "Microfacet models for refraction through rough surfaces", EGSR 2007); unit normal n,
    towards-light l and towards-eye e."""
    alpha2 = max(roughness, 0.02) ** 4
    hx, hy, hz = lx + ex, ly + ey, lz + ez
    length = max(np.sqrt(hx * hx + hy * hy + hz * hz), 1e-9)
    hx, hy, hz = hx / length, hy / length, hz / length
    nh = min(max(nx * hx + ny * hy + nz * hz, 0.0), 1.0)
    nl = min(max(nx * lx + ny * ly + nz * lz, 1e-3), 1.0)
    nv = min(max(nx * ex + ny * ey + nz * ez, 1e-3), 1.0)
    d = alpha2 / (np.pi * (nh**2 * (alpha2 - 1) + 1) ** 2)
    g_l = 2 * nl / (nl + np.sqrt(alpha2 + (1 - alpha2) * nl**2))
    g_v = 2 * nv / (nv + np.sqrt(alpha2 + (1 - alpha2) * nv**2))
    return d * g_l * g_v / (4 * nl * nv)


@numba.njit(cache=True, nogil=True)
def _irradiance(px, py, pz, nx, ny, nz, positions, intensities, facings, suns, sun_irradiance):
    """Lighting's point and area lights (inverse square, an area light's cosine about its facing) and suns at
    one surface point; unshadowed."""
    out = 0.0
    for k in range(positions.shape[0]):
        dx, dy, dz = positions[k, 0] - px, positions[k, 1] - py, positions[k, 2] - pz
        r2 = max(dx * dx + dy * dy + dz * dz, 1e-6)
        r = np.sqrt(r2)
        dx, dy, dz = dx / r, dy / r, dz / r
        emitted = intensities[k]
        if facings[k, 0] != 0.0 or facings[k, 1] != 0.0 or facings[k, 2] != 0.0:
            emitted *= max(-dx * facings[k, 0] - dy * facings[k, 1] - dz * facings[k, 2], 0.0)
        out += emitted * max(nx * dx + ny * dy + nz * dz, 0.0) / r2
    for k in range(suns.shape[0]):
        out += sun_irradiance[k] * max(nx * suns[k, 0] + ny * suns[k, 1] + nz * suns[k, 2], 0.0)
    return out


@numba.njit(cache=True, nogil=True)
def _shade(depth, normals, albedo, gloss, roughness, K, T_base_cam, T_proj_cam, T_proj_base, projector, table, size,
           scale, max_footprint, shadow, shadow_K, intensity, positions, intensities, facings, suns, sun_irradiance,
           world, out):
    """radiance per pixel, in one pass: the pixel's point and normal in the camera and the base frame, the
    dots over its footprint by the Lambertian and GGX lobes where the projector sees it, the ambient lights,
    the world."""
    R, t = T_base_cam[:3, :3], T_base_cam[:3, 3]
    for v in range(depth.shape[0]):
        for u in range(depth.shape[1]):
            d = depth[v, u]
            if d <= 0:
                out[v, u] = world
                continue
            cx, cy = (u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d
            px, py, pz = _moved(T_base_cam, cx, cy, d)
            nx, ny, nz = normals[v, u, 0], normals[v, u, 1], normals[v, u, 2]
            lx, ly, lz = projector[0] - px, projector[1] - py, projector[2] - pz
            r2 = max(lx * lx + ly * ly + lz * lz, 1e-6)
            r = np.sqrt(r2)
            lx, ly, lz = lx / r, ly / r, lz / r
            dots = 0.0
            if _sees(px, py, pz, T_proj_base, shadow, shadow_K):
                mx, my, mz = _rotated_back(R, nx, ny, nz)
                share = _footprint_mean(u, v, d, mx, my, mz, cx, cy, d, K, T_proj_cam, table, size, scale,
                                        max_footprint)
                dots = intensity * share * max(nx * lx + ny * ly + nz * lz, 0.0) / r2
            ex, ey, ez = t[0] - px, t[1] - py, t[2] - pz
            length = max(np.sqrt(ex * ex + ey * ey + ez * ez), 1e-9)
            ex, ey, ez = ex / length, ey / length, ez / length
            specular = gloss[v, u] * ggx_specular(nx, ny, nz, lx, ly, lz, ex, ey, ez, roughness[v, u])
            ambient = _irradiance(px, py, pz, nx, ny, nz, positions, intensities, facings, suns, sun_irradiance)
            out[v, u] = albedo[v, u] / np.pi * (dots + ambient) + specular * dots + albedo[v, u] * world


def radiance(g: GBuffer, projector: Projector, lighting: Lighting) -> np.ndarray:
    """Radiance (W / (m^2 sr), luminance) each pixel of the imager receives; where the ray hits nothing,
    the world's. One compiled pass over the pixels (numpy's arrays of points, normals and footprints cost
    twice the shading itself)."""
    T_proj_base = inv_T(projector.T_base_proj)
    pattern = projector.pattern
    out = np.empty(g.depth.shape)
    _shade(*_f64(g.depth, g.normal, g.albedo, g.gloss, g.roughness, g.K, g.T_base_cam, T_proj_base @ g.T_base_cam,
                 T_proj_base, projector.T_base_proj[:3, 3]), pattern.table, pattern.size, pattern.scale, MAX_FOOTPRINT,
           *_f64(projector.shadow_depth, projector.shadow_K), float(projector.intensity),
           *_f64(lighting.positions, lighting.intensities, lighting.facings, lighting.suns, lighting.sun_irradiance),
           float(lighting.world_radiance), out)
    return out


def _f64(*arrays):
    return tuple(np.ascontiguousarray(a, dtype=np.float64) for a in arrays)


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
