"""Placeholder (helper "stages"): :func:`observation_reference`, the numpy reference of
:meth:`~deploy.spec.policy_spec.PolicySpec.observation`, with the agreed name and signature; it
delegates to today's ``spec.observation(..., reference=True)``. Helper "spec" owns the real one,
which replaces this file at merge.
"""

from __future__ import annotations

import numpy as np


def observation_reference(spec, state, goal, out=None) -> np.ndarray:
    """``spec.observation(state, goal, out=out)`` in numpy."""
    return spec.observation(state, goal, out=out, reference=True)
