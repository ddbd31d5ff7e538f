"""Bag-of-words template retrieval after FoundPose: PCA, k-means words, assignment to the 3 nearest words,
TF-IDF, cosine similarity between a query and every template.

Two assignments (`assignment`):
- "foundpose" (the default; FoundPose's released code with its defaults): equal votes for the 3 nearest
  words, a word present in a template (for IDF) when it is the nearest word of one of its features,
  k-means on every template feature;
- "gaussian" (ours, the default before): a feature's vote over its 3 nearest words is weighted by a
  Gaussian of the distance (width: the median nearest-word distance of the template features), a word
  present in a template when it is among the 3 nearest words of one of its features, k-means on the PCA
  sample. On 96 `mini` frames (2F-85, Kinova-3F; docs/feepe.md) variant D scored 72.2/80.6 AUC@1cm ADD/ADD-S
  with "foundpose" against 68.8/78.0, variant A 9.0/22.4 against 9.2/23.6.
Both fit PCA on at most 100k features. Matching (feepe/matching.py) uses the raw unit descriptors, not the
PCA space FoundPose matches in; see docs/feepe.md (BoW, after FoundPose) for what that changes."""

from __future__ import annotations

from dataclasses import dataclass

import faiss
import numpy as np


@dataclass
class BowIndex:
    mean: np.ndarray  # (D,)
    components: np.ndarray  # (D, d) PCA projection
    words: np.ndarray  # (n_words, d)
    sigma: float  # soft-assignment kernel width
    idf: np.ndarray  # (n_words,)
    template_vectors: np.ndarray  # (T, n_words) unit TF-IDF vectors
    knn: int = 3
    assignment: str = "foundpose"

    def __post_init__(self):
        self._words_sq = np.sum(self.words**2, 1)

    def project(self, desc: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(((desc - self.mean) @ self.components).astype(np.float32))

    def nearest_words(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Squared distances and ids of the `knn` nearest words of projected features x (N, d)."""
        d2 = np.sum(x**2, 1)[:, None] - 2.0 * (x @ self.words.T) + self._words_sq
        rows, ids = np.arange(len(x)), np.zeros((len(x), self.knn), int)
        for k in range(self.knn):  # k argmin passes beat a partition for k = 3
            ids[:, k] = d2.argmin(1)
            if k + 1 < self.knn:
                d2[rows, ids[:, k]] = np.inf
        return np.sum((x[:, None, :] - self.words[ids]) ** 2, -1), ids

    def histogram(self, desc: np.ndarray) -> np.ndarray:
        d2, ids = self.nearest_words(self.project(desc))
        return _histogram(d2, ids, len(self.words), self.sigma if self.assignment == "gaussian" else None)

    def vector(self, desc: np.ndarray) -> np.ndarray:
        """Unit TF-IDF vector of one image's descriptors."""
        v = self.histogram(desc) * self.idf
        return v / max(np.linalg.norm(v), 1e-12)

    def retrieve(self, desc: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Indices and cosine similarities of the k most similar templates, best first."""
        sims = self.template_vectors @ self.vector(desc)
        order = np.argsort(-sims, kind="stable")[:k]
        return order, sims[order]


def _histogram(d2: np.ndarray, ids: np.ndarray, n_words: int, sigma: float | None) -> np.ndarray:
    """Each feature spreads a unit vote over its nearest words (squared distances d2, word ids), weighted by
    a Gaussian kernel of width sigma or, without sigma, equally; normalised by the number of features."""
    hist = np.zeros(n_words)
    if len(d2) == 0:
        return hist
    w = np.ones_like(d2) if sigma is None else np.exp(-(d2 - d2.min(1, keepdims=True)) / (2.0 * sigma**2))
    w /= w.sum(1, keepdims=True)
    np.add.at(hist, ids.ravel(), w.ravel())
    return hist / len(d2)


def build_index(per_template: list[np.ndarray], n_words: int = 2048, dims: int = 256, n_fit: int = 100_000,
                iterations: int = 50, knn: int = 3, seed: int = 0, assignment: str = "foundpose") -> BowIndex:
    """Fit PCA (and, for "gaussian", the words) on at most `n_fit` template features. A small template set
    gets fewer words: faiss wants >= 39 training points per word, so n_words is capped at n_features / 39."""
    if assignment not in ("gaussian", "foundpose"):
        raise ValueError(f"BoW assignment {assignment!r}: gaussian or foundpose")
    rng = np.random.default_rng(seed)
    every = np.concatenate(per_template).astype(np.float32)
    fit = every[rng.choice(len(every), min(n_fit, len(every)), replace=False)]
    mean = fit.mean(0)
    dims = min(dims, fit.shape[1])
    _, _, vt = np.linalg.svd(fit - mean, full_matrices=False)
    components = vt[:dims].T.astype(np.float32)
    projected = np.ascontiguousarray(((fit if assignment == "gaussian" else every) - mean) @ components,
                                     dtype=np.float32)
    n_words = int(max(16, min(n_words, len(projected) // 39)))
    kmeans = faiss.Kmeans(dims, n_words, niter=iterations, seed=seed, verbose=False, max_points_per_centroid=10_000)
    kmeans.train(projected)
    d2, _ = kmeans.index.search(projected, 1)  # the trained words' own faiss index
    sigma = float(np.sqrt(max(np.median(d2), 1e-12)))

    index = BowIndex(mean, components, kmeans.centroids.copy(), sigma, np.ones(n_words),
                     np.zeros((len(per_template), n_words)), knn, assignment)
    hists = np.stack([index.histogram(f) for f in per_template])
    if assignment == "gaussian":
        present = (hists > 0).sum(0)
    else:
        present = np.zeros(n_words)
        for f in per_template:
            if len(f):
                present[np.unique(index.nearest_words(index.project(f))[1][:, 0])] += 1
    index.idf = np.log(len(per_template) / np.maximum(present, 1))
    tfidf = hists * index.idf
    index.template_vectors = tfidf / np.maximum(np.linalg.norm(tfidf, axis=1, keepdims=True), 1e-12)
    return index
