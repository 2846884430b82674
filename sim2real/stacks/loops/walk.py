"""The push schedule's view of an own loop (:class:`Walk`)."""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING


class Walk:
    """What :class:`~sim2real.eval.world.pushes.DomainPushes` reads of a runtime, for a loop that
    is not ours: ``ticks`` (the loop sets it each policy tick) and ``mode`` ((1,) int8, always
    RUNNING)."""

    def __init__(self):
        self.ticks, self.mode = 0, np.array([RUNNING])
