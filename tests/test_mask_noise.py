"""The segmenter-like mask perturbation of the evaluation (`--mask-noise sam`): seeded per frame, the
boundary moved within its amplitude, blobs and holes where they are described."""

import cv2
import numpy as np
import pytest

from eval.mask_noise import MaskNoise, frame_rng, mask_noise, perturb
from kernel.errors import UserError


def _gripper_mask() -> np.ndarray:
    """A palm (disc) with two thin fingers, in a 240x320 frame."""
    m = np.zeros((240, 320), np.uint8)
    cv2.circle(m, (160, 150), 40, 1, -1)
    m[40:120, 130:136] = 1
    m[40:120, 184:190] = 1
    return m > 0


def _distance_to_boundary(mask: np.ndarray) -> np.ndarray:
    m = mask.astype(np.uint8)
    return np.maximum(cv2.distanceTransform(m, cv2.DIST_L2, 5), cv2.distanceTransform(1 - m, cv2.DIST_L2, 5))


def test_same_frame_same_mask_other_frame_other_mask():
    noise, mask = mask_noise("sam", seed=3), _gripper_mask()
    a = perturb(mask, noise, frame_rng(noise, 5, 7))
    assert np.array_equal(a, perturb(mask, noise, frame_rng(noise, 5, 7)))
    assert not np.array_equal(a, perturb(mask, noise, frame_rng(noise, 5, 8)))
    other = mask_noise("sam", seed=4)
    assert not np.array_equal(a, perturb(mask, other, frame_rng(other, 5, 7)))


def test_boundary_moves_within_its_amplitude_both_ways():
    mask, near = _gripper_mask(), _distance_to_boundary(_gripper_mask())
    noise = MaskNoise(max_blobs=0, max_holes=0)
    grown = shrunk = 0
    for im_id in range(20):
        out = perturb(mask, noise, frame_rng(noise, 0, im_id))
        changed = out != mask
        assert changed.any()
        assert near[changed].max() <= noise.boundary_px[1] + 0.5
        grown += np.count_nonzero(out & ~mask)
        shrunk += np.count_nonzero(mask & ~out)
    assert grown > 0 and shrunk > 0


def test_blobs_outside_and_holes_inside():
    mask, near = _gripper_mask(), _distance_to_boundary(_gripper_mask())
    blobs = MaskNoise(boundary_px=(0.0, 0.0), max_blobs=2, max_holes=0)
    holes = MaskNoise(boundary_px=(0.0, 0.0), max_blobs=0, max_holes=2)
    added = removed = 0
    for im_id in range(20):
        out = perturb(mask, blobs, frame_rng(blobs, 0, im_id))
        assert not (mask & ~out).any()
        added += np.count_nonzero(out & ~mask)
        out = perturb(mask, holes, frame_rng(holes, 0, im_id))
        assert not (out & ~mask).any()
        removed += np.count_nonzero(mask & ~out)
    far = blobs.blob_reach_px + np.sqrt(blobs.blob_area[1] * mask.sum() / (0.4 * np.pi))  # reach + widest blob
    assert added > 0 and removed > 0
    out = perturb(mask, blobs, frame_rng(blobs, 0, 1))
    assert near[out & ~mask].max(initial=0) <= far


def test_empty_stays_empty_and_names_are_checked():
    noise = mask_noise("sam")
    assert not perturb(np.zeros((10, 10), bool), noise, frame_rng(noise, 0, 0)).any()
    assert mask_noise("none") is None
    with pytest.raises(UserError, match="--mask-noise 'blur' unknown"):
        mask_noise("blur")
    with pytest.raises(UserError, match="--mask-seed -1"):
        mask_noise("sam", seed=-1)
