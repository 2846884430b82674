"""Placeholder (helper "stages"): :class:`ReferenceGuard`, the numpy reference of the guard, with
the agreed name and signature; it delegates to today's ``SafetyGuard(..., reference=True)``.
Helper "safety" owns the real one, which replaces this file at merge.
"""

from __future__ import annotations

from deploy.safety.guard import SafetyGuard


class ReferenceGuard(SafetyGuard):
    """A :class:`~deploy.safety.guard.SafetyGuard` running its numpy reference."""

    def __init__(self, robot, envs, mode):
        super().__init__(robot, envs, mode, reference=True)
