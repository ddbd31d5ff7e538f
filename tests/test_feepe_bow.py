"""BoW retrieval on synthetic descriptors: each template draws from its own mixture of word centres."""

import numpy as np
import pytest

from feepe.bow import build_index


def _unit(x):
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


@pytest.mark.parametrize("assignment", ["gaussian", "foundpose"])
def test_query_retrieves_the_template_it_was_drawn_from(assignment):
    rng = np.random.default_rng(0)
    centres = rng.normal(size=(64, 32))
    mixtures = [rng.choice(64, 8, replace=False) for _ in range(20)]  # template t uses 8 of 64 centres

    def draw(t, n):
        return _unit(centres[rng.choice(mixtures[t], n)] + rng.normal(0, 0.15, (n, 32)))

    index = build_index([draw(t, 300) for t in range(20)], n_words=64, dims=16, iterations=20, assignment=assignment)
    assert index.words.shape == (64, 16) and index.template_vectors.shape == (20, 64)
    np.testing.assert_allclose(np.linalg.norm(index.template_vectors, axis=1), 1.0, atol=1e-9)
    for t in range(20):
        order, sims = index.retrieve(draw(t, 200), 3)
        assert order[0] == t and sims[0] > sims[1]


def test_words_capped_by_the_number_of_features():
    rng = np.random.default_rng(1)
    index = build_index([_unit(rng.normal(size=(100, 8))) for _ in range(10)], n_words=2048)
    assert len(index.words) == 1000 // 39


def test_foundpose_assignment_idf_and_votes():
    """FoundPose's code: a word is present in a template when it is the nearest word of one of its features
    (IDF), and each feature votes equally for its 3 nearest words; recomputed here by brute force."""
    rng = np.random.default_rng(2)
    per = [_unit(rng.normal(size=(120, 8)) + rng.normal(size=8)) for _ in range(12)]
    index = build_index(per, n_words=32, dims=6, iterations=10, assignment="foundpose")

    def d2(f):
        x = (f - index.mean) @ index.components
        return ((x[:, None, :] - index.words[None]) ** 2).sum(-1)

    present = np.zeros(len(index.words))
    for f in per:
        present[np.unique(d2(f).argmin(1))] += 1
    np.testing.assert_allclose(index.idf, np.log(12 / np.maximum(present, 1)), rtol=1e-6)
    hist = np.zeros(len(index.words))
    np.add.at(hist, np.argsort(d2(per[0]), 1)[:, :3].ravel(), 1.0)
    expected = hist * index.idf
    np.testing.assert_allclose(index.template_vectors[0], expected / np.linalg.norm(expected), atol=1e-6)
