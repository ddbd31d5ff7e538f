"""The shaded IR pair (syneepose/ir_shading.py): the pattern averaged over a pixel's footprint, the
projector's shadow test, the ambient light, and the imager's exposure and noise - plain numpy, no Blender."""

import numpy as np

from kernel.camera import point_map
from kernel.transforms import make_T
from syneepose.colour import linear_to_srgb, srgb_to_linear
from syneepose.ir_shading import (DotPattern, GBuffer, Lighting, Projector, box_mean, dot_share, expose,
                                  projector_depth, projector_sees, radiance)
from syneepose.scene.spec import Light


def _pattern(size=90, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.uniform(size=(size, size)) < 0.3).astype(np.uint8) * 255


def test_box_mean_is_the_exact_mean_of_the_pattern_under_a_fractional_box():
    pattern = _pattern()
    dots = DotPattern(pattern, 90.0)
    # a box from (10.25, 20.5) to (13.75, 22.5): whole pixels plus fractions of the border ones, by brute force
    fine = np.kron(pattern.astype(float) / 255, np.ones((4, 4)))  # quarter-pixel cells
    expected = fine[82:90, 41:55].mean()
    got = box_mean(dots.table, dots.size, 10.25, 20.5, 13.75, 22.5)
    assert abs(got - expected) < 1e-12
    assert box_mean(dots.table, dots.size, 5.0, 5.0, 5.0, 7.0) == 0.0  # an empty box


def _wall(distance, size=(40, 30), f=30.0, albedo=0.5, gloss=0.0):
    """A G-buffer of a wall facing an imager at the origin of the base frame."""
    h, w = size[1], size[0]
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    normal = np.broadcast_to([0.0, 0.0, -1.0], (h, w, 3)).copy()
    return GBuffer(np.full((h, w), distance), normal, np.full((h, w), albedo), np.full((h, w), gloss),
                   np.full((h, w), 0.4), K, np.eye(4))


def test_a_wall_facing_a_projector_in_the_imager_averages_the_pattern_over_each_pixel():
    """Projector and imager at one place with the pattern 3 pattern pixels to an imager pixel: each pixel's
    footprint is its 3 x 3 pattern pixels, at any distance."""
    g = _wall(1.3)
    size = 180  # over 90 deg: a focal length of 90 pattern pixels, 3x the imager's 30
    pattern = _pattern(size)
    projector = Projector(np.eye(4), DotPattern(pattern, 90.0), 1.0, np.full((30, 40), 1.3), g.K)
    share = dot_share(g, projector, point_map(g.depth, g.K))
    # imager pixel (u, v) spans pattern columns 3 (u - cx) + size / 2 -/+ 1.5
    v, u = 12, 17
    c0 = int(round(3 * (u - g.K[0, 2]) + size / 2 - 1.5))
    r0 = int(round(3 * (v - g.K[1, 2]) + size / 2 - 1.5))
    assert abs(share[v, u] - pattern[r0:r0 + 3, c0:c0 + 3].mean() / 255) < 1e-9


def test_what_the_projector_does_not_see_gets_no_dots():
    g = _wall(2.0)
    seen = np.full((30, 40), 2.0)
    seen[:, :20] = 1.0  # something nearer hides the left half of the wall from the projector
    projector = Projector(np.eye(4), DotPattern(np.full((90, 90), 255, np.uint8), 90.0), 1.0, seen, g.K)
    lit = projector_sees(projector, point_map(g.depth, g.K))  # the imager at the base frame's origin
    assert not lit[:, :19].any() and lit[:, 21:].all()
    image = radiance(g, projector, Lighting.of([], (0, 0, 0), 0.0, 0.1))
    assert (image[:, :19] == 0).all() and (image[:, 21:] > 0).all()


def test_ambient_light_follows_the_inverse_square_law_and_the_world_adds_its_radiance():
    T_light = make_T(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.0])  # a point light at the imager
    light = Light("POINT", T_light, (1.0, 1.0, 1.0), 100.0, 0.01)
    dark = Projector(np.eye(4), DotPattern(np.zeros((90, 90), np.uint8), 90.0), 1.0, np.full((30, 40), 1.0), np.eye(3))
    near, far = (radiance(_wall(z), dark, Lighting.of([light], (0.2, 0.2, 0.2), 1.0, 0.1)) for z in (1.0, 2.0))
    world = 0.1 * 1.0 * 0.2 * 0.5  # share x strength x colour's luminance x albedo
    centre = (15, 20)
    assert abs((near[centre] - world) / (far[centre] - world) - 4.0) < 0.01
    wall = _wall(1.0)
    point = point_map(wall.depth, wall.K)[centre]
    r = np.linalg.norm(point)
    irradiance = 0.1 * 100 / (4 * np.pi) * (point[2] / r) / r**2  # share x P / (4 pi) x cosine / r^2
    assert abs(near[centre] - world - 0.5 / np.pi * irradiance) < 1e-12


def test_a_black_surface_facing_the_projector_returns_its_dots_by_the_specular_lobe():
    """No diffuse albedo, the glossy colour of a dielectric: bright where it faces the projector and the
    imager, dark when it is turned 40 deg away."""
    lit = Projector(np.eye(4), DotPattern(np.full((180, 180), 255, np.uint8), 90.0), 1.0,
                    np.full((30, 40), 1.0), np.eye(3))
    lighting = Lighting.of([], (0, 0, 0), 0.0, 0.1)
    facing = _wall(1.0, albedo=0.0, gloss=0.04)
    turned = _wall(1.0, albedo=0.0, gloss=0.04)
    turned.normal[:] = [np.sin(np.deg2rad(40)), 0.0, -np.cos(np.deg2rad(40))]
    grey = _wall(1.0, albedo=0.5)
    centre = (15, 20)
    shine, side, diffuse = (radiance(g, lit, lighting)[centre] for g in (facing, turned, grey))
    assert shine > 0.5 * diffuse and side < 0.01 * shine


def test_exposure_is_shared_by_both_images_and_the_noise_is_seeded():
    rng = np.random.default_rng(1)
    left = rng.uniform(0.0, 2.0, (60, 80))
    right = 0.5 * left
    a = expose(left, right, 0.0, 0.8, 1e9, 0.0, np.random.default_rng([3, 0]))
    white = 255 * linear_to_srgb(0.8)  # the left image's 99th percentile at 80 % of full scale, sRGB-encoded
    assert abs(np.percentile(a[0], 99) - white) <= 1
    decoded = [srgb_to_linear(image / 255.0) for image in a]
    assert abs(decoded[1].mean() / decoded[0].mean() - 0.5) < 0.01  # the right one under the same gain
    noisy = [expose(left, right, 0.7, 0.8, 175.0, 1.0, np.random.default_rng([3, f])) for f in (0, 0, 1)]
    np.testing.assert_array_equal(noisy[0][0], noisy[1][0])
    assert (noisy[0][0] != noisy[2][0]).mean() > 0.5


def test_the_projector_depth_splatted_from_two_imagers_matches_what_the_projector_sees():
    """A wall 2 m away and a plate 1 m away in front of its middle, seen by two imagers 50 mm apart with the
    projector between them: the splatted map holds the plate's and the wall's depth where the projector sees
    each (on the axis, 2 px off the plate's edges), and lights the wall pixels the rendered map would light."""
    w, h, f = 80, 60, 60.0
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])

    def scene_depth(T_base_cam, Km, size):
        """Depth along the axis of a camera looking down +z from T_base_cam's origin (rotation identity)."""
        u, v = np.meshgrid(np.arange(size[0], dtype=float), np.arange(size[1], dtype=float))
        rx, ry = (u - Km[0, 2]) / Km[0, 0], (v - Km[1, 2]) / Km[1, 1]
        ox = T_base_cam[0, 3]
        on_plate = (np.abs(ox + rx * 1.0) <= 0.15) & (np.abs(ry * 1.0) <= 0.15)
        return np.where(on_plate, 1.0, 2.0)

    views = []
    for x in (0.0, 0.05):
        T = make_T(t=[x, 0.0, 0.0])
        normal = np.broadcast_to([0.0, 0.0, -1.0], (h, w, 3)).copy()
        views.append(GBuffer(scene_depth(T, K, (w, h)), normal, np.full((h, w), 0.5), np.zeros((h, w)),
                             np.full((h, w), 0.4), K, T))
    T_proj = make_T(t=[0.025, 0.0, 0.0])
    splat = projector_depth(views, T_proj, K, (h, w))
    truth = scene_depth(T_proj, K, (w, h))
    covered = splat > 0
    assert covered[:, 2:-2].all()  # the two imagers' splats leave no hole inside the field both see
    np.testing.assert_allclose(splat[covered], truth[covered])
    for g in views:
        points = point_map(g.depth, g.K) + g.T_base_cam[:3, 3]
        lit = projector_sees(Projector(T_proj, None, 1.0, splat, K), points)
        np.testing.assert_array_equal(lit, projector_sees(Projector(T_proj, None, 1.0, truth, K), points))
        assert 0 < (~lit).sum() < 0.05 * lit.size  # the plate's thin shadow on the wall, beside its edge
