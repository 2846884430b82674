"""The checks every range of a session's draw runs: one message naming the range."""

from __future__ import annotations

import numpy as np


def check_range(owner: str, name: str, lo: float, hi: float, minimum: float = 0.0) -> None:
    """Raise ``ValueError`` naming ``owner.name`` unless ``minimum <= lo <= hi``, both finite."""
    if not (np.isfinite(lo) and np.isfinite(hi) and minimum <= lo <= hi):
        raise ValueError(
            f"{owner}.{name}: expected a range (low, high) with {minimum} <= low <= high, "
            f"got ({lo}, {hi})"
        )
