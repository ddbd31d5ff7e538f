"""2D-2D matches between a query and a template: cyclic best buddies under cosine similarity."""

from __future__ import annotations

import numpy as np


def best_buddies(query: np.ndarray, template: np.ndarray, max_matches: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i_query, i_template) that are each other's nearest neighbour, the `max_matches` most similar,
    and their similarities; descriptors are unit rows."""
    if len(query) == 0 or len(template) == 0:
        return np.zeros((0, 2), int), np.zeros(0)
    sims = query @ template.T
    nn_q = sims.argmax(1)
    nn_t = sims.argmax(0)
    mutual = np.flatnonzero(nn_t[nn_q] == np.arange(len(query)))
    pairs = np.stack([mutual, nn_q[mutual]], 1)
    score = sims[pairs[:, 0], pairs[:, 1]]
    order = np.argsort(-score, kind="stable")[:max_matches]
    return pairs[order], score[order]
