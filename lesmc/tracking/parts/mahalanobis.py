"""The Mahalanobis hypothesiser: how far each detection lies from each track's predicted
measurement, d = sqrt((z − Hx̂)ᵀ S⁻¹ (z − Hx̂)) (Stone Soup's ``Mahalanobis`` measure on the
predicted measurement), and the chi-square gate: a pair is admissible when d² is below
the χ² quantile of ``probability`` with 2 degrees of freedom, −2 ln(1 − probability)
(``DistanceHypothesiser``'s ``missed_distance`` is its square root; admission is strict,
d < gate, as there)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MahalanobisHypothesiser:
    """Mahalanobis distances with a χ² gate of probability in (0, 1)."""

    probability: float = 0.99

    def __post_init__(self) -> None:
        if not 0 < self.probability < 1:
            raise ValueError(f"a gate probability must lie in (0, 1), got {self.probability!r}")

    @property
    def gate2(self) -> float:
        """The gate on d²: the χ²(2) quantile of the probability."""
        return -2.0 * math.log1p(-self.probability)

    @property
    def gate(self) -> float:
        """The gate on d (the distance a missed detection costs the associator)."""
        return math.sqrt(self.gate2)

    def scores(self, d2: np.ndarray) -> np.ndarray:
        """Distances d (detections, tracks) from squared distances; ∞ outside the gate (a
        d² rounded below 0 is 0)."""
        d = np.sqrt(np.maximum(d2, 0.0))
        out: np.ndarray = np.where(d < self.gate, d, np.inf)
        return out
