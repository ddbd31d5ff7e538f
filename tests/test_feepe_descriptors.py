"""OpenCV-contrib descriptors on FEEPE's dense grid (issue 13, item 4): every grid point kept, in order."""

import cv2
import numpy as np
import pytest

from feepe.backbones import DEFAULT, get_backbone
from feepe.backbones.contrib import NAMES, ContribDescriptor
from feepe.crop import Crop


def _texture(size: int, seed: int = 0) -> np.ndarray:
    noise = np.random.default_rng(seed).random((size, size)).astype(np.float32)
    return cv2.normalize(cv2.GaussianBlur(noise, (0, 0), 2.0), None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


@pytest.mark.parametrize("name", NAMES)
def test_every_grid_point_is_described_in_order_and_matches_its_shifted_self(name):
    """Border points kept, rows follow the points (a permutation of the points permutes the rows), and
    in a shifted image each interior point's nearest descriptor is its own shifted point."""
    big = _texture(160)
    shift = 8
    a, b = big[:144, :144], big[shift:shift + 144, shift:shift + 144]
    uv = np.stack(np.meshgrid(np.arange(32.0, 120, 6), np.arange(32.0, 120, 6)), -1).reshape(-1, 2)
    engine = ContribDescriptor(name, 16.0)
    border = np.array([[1.0, 1.0], [142.0, 142.0], [0.0, 100.0]])
    da = engine.compute(a, np.concatenate([uv, border]))
    assert da.shape[0] == len(uv) + 3 and np.allclose(np.linalg.norm(da, axis=1), 1.0, atol=1e-5)
    order = np.random.default_rng(1).permutation(len(uv))
    assert np.allclose(engine.compute(a, uv[order]), da[:len(uv)][order], atol=1e-6)
    db = engine.compute(b, uv - shift)
    nearest = np.argmax(da[:len(uv)] @ db.T, axis=1)
    assert np.mean(nearest == np.arange(len(uv))) >= 0.8


def test_binary_descriptors_compare_by_hamming_distance():
    uv = np.array([[30.0, 30.0], [60.0, 40.0]])
    img = _texture(96)
    d = ContribDescriptor("teblid", 16.0).compute(img, uv)
    raw = ContribDescriptor("teblid", 16.0)._engine.compute(
        cv2.copyMakeBorder(img, 48, 48, 48, 48, cv2.BORDER_CONSTANT, value=0),
        [cv2.KeyPoint(x + 48, y + 48, 16.0, 0.0) for x, y in uv])[1]
    hamming = np.count_nonzero(np.unpackbits(raw[0] ^ raw[1]))
    assert d[0] @ d[1] == pytest.approx(1 - 2 * hamming / 256, abs=1e-5)


def test_contrib_parts_join_the_weight_free_backbone():
    rgb = np.repeat(_texture(128)[..., None], 3, axis=2)
    mask = np.zeros((128, 128), bool)
    mask[20:110, 16:112] = True
    K = np.array([[300.0, 0, 63.5], [0, 300.0, 63.5], [0, 0, 1]])
    crop = Crop(rgb, np.where(mask, 1.0, 0.0), mask, K, np.eye(3))
    net = get_backbone("teblid+normals+color")
    features = net.extract(crop)
    assert features.desc.shape[1] == 256 + 48 + 48
    assert net.options()["weights"] == {"teblid": 1.0, "normals": 1.0, "color": 0.5}


def test_a_mask_with_no_grid_point_gives_no_features():
    """A mask too thin to hold a grid point (the estimator's own end-effector mask can be a sliver) gives no
    features, not an error: the frame is then a no-estimate of the template path."""
    rng = np.random.default_rng(0)
    mask = np.zeros((128, 128), bool)
    mask[60, 10:120] = True  # one row: the eroded grid holds no point
    crop = Crop(rng.integers(0, 256, (128, 128, 3), dtype=np.uint8), np.full((128, 128), 0.5), mask,
                np.array([[150.0, 0, 64], [0, 150.0, 64], [0, 0, 1]]), np.eye(3))
    feats = get_backbone(DEFAULT).extract(crop)
    assert len(feats.uv) == 0 and len(feats.desc) == 0
