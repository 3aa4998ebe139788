"""The shared schema: the 14 environment features in their fixed order, and the class names.

``models`` imports only this module of ``features`` (docs/style.md). The names are
written out here, not imported from the sensor packages, so that importing the
schema costs nothing; ``tests/test_schema.py`` checks that they equal
:data:`features.gnss.features.FEATURE_COLUMNS` and
:data:`features.acoustic.cir.FEATURE_NAMES`.

>>> len(FEATURES), FEATURES[0], FEATURES[5]
(14, 'att_mean_db', 'mean_excess_delay_ms')
"""

from __future__ import annotations

from features.site import ENV_CLASSES

__all__ = ["GNSS_FEATURES", "ACOUSTIC_FEATURES", "FEATURES", "ENV_CLASSES", "MODALITIES", "modality_columns"]

GNSS_FEATURES = ("att_mean_db", "att_std_db", "fluct_per_s", "invisible_ratio", "dop_growth")
"""The five GNSS features of docs/design.md §5 (μ, σ, β, ζ, λ), in order."""

ACOUSTIC_FEATURES = ("mean_excess_delay_ms", "rms_delay_ms", "delay_kurtosis", "delay_skewness", "rician_k_db",
                     "gain_mean_db", "gain_rms_db", "gain_kurtosis", "gain_skewness")
"""The nine acoustic CIR features of docs/design.md §5, in order."""

FEATURES = GNSS_FEATURES + ACOUSTIC_FEATURES
"""All 14 features: the column order of every feature matrix, library row and model."""

MODALITIES = ("gnss", "acoustic")
"""The two sensor groups a window may have or lack."""


def modality_columns(modality: str) -> tuple[int, ...]:
    """Column indices of ``modality`` (``"gnss"`` or ``"acoustic"``) in :data:`FEATURES`.

    >>> modality_columns("gnss")
    (0, 1, 2, 3, 4)
    """
    if modality == "gnss":
        return tuple(range(len(GNSS_FEATURES)))
    if modality == "acoustic":
        return tuple(range(len(GNSS_FEATURES), len(FEATURES)))
    raise ValueError(f"modality must be one of {MODALITIES}, got {modality!r}")
