"""A synthetic 14-feature fingerprint library whose environment classes are known.

Windows of three classes (open / light / heavy, severity 0 / 1 / 2) with the direction of
docs/design.md §5: attenuation, its spread, fluctuations, invisible ratio, DOP growth and delay
spread grow with severity, the Rician K falls; the shape features (kurtosis, skewness, gain
statistics) are noise of the same size in every class. Not physics: a test fixture with a
right answer, for the severity naming and for timing the embedding.
"""

from __future__ import annotations

import numpy as np

from models.embedding import ENV_FEATURES

# per feature: (value at severity 0, change per severity step, noise SD)
_MODEL = {
    "att_mean_db": (2.0, 5.0, 1.5), "att_std_db": (1.5, 1.5, 0.8), "fluct_per_s": (0.2, 0.25, 0.15),
    "invisible_ratio": (0.03, 0.15, 0.05), "dop_growth": (0.05, 0.35, 0.12),
    "mean_excess_delay_ms": (0.3, 0.4, 0.2), "rms_delay_ms": (0.4, 0.5, 0.2),
    "delay_kurtosis": (3.0, 0.0, 1.0), "delay_skewness": (1.0, 0.0, 0.5),
    "rician_k_db": (12.0, -4.0, 2.0), "gain_mean_db": (-10.0, 0.0, 2.0), "gain_rms_db": (4.0, 0.0, 1.0),
    "gain_kurtosis": (2.5, 0.0, 0.8), "gain_skewness": (0.0, 0.0, 0.5),
}

CLASSES = ("open", "light", "heavy")


def synthetic_library(n: int, seed: int, shares=(0.5, 0.3, 0.2)) -> tuple[np.ndarray, np.ndarray]:
    """``samples`` of shape (n, 14) in :data:`models.embedding.ENV_FEATURES` order and the class
    index (0 open, 1 light, 2 heavy) of every row, shuffled."""
    rng = np.random.default_rng(seed)
    y = rng.choice(3, size=n, p=np.asarray(shares) / np.sum(shares))
    X = np.empty((n, len(ENV_FEATURES)))
    for j, name in enumerate(ENV_FEATURES):
        base, step, sd = _MODEL[name]
        X[:, j] = base + step * y + rng.normal(0.0, sd, n)
    return X, y
