"""What the soak's operator does with a robot of each kind (:data:`OPERATOR_OF_KIND`, a face
registered under the kind's name in this room, :class:`sim2real.deploy.core.registry.Faces`):
before clearing a latched fault (:meth:`HoldsPose.before_reset`) and which of its stops the soak
replays without the stop (:meth:`HoldsPose.replays`).

An arm holds its pose in a stop (:class:`HoldsPose`): the operator clears the fault, nothing is
replayed. A legged robot lies down, damped, in every stop (:class:`LiesDown`): the operator
stands it up first, and the soak replays a stop (and a fall) without it
(:class:`sim2real.eval.soak.counterfactual.StopReplay`,
:class:`sim2real.eval.soak.fall_replay.FallReplay`).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.registry import Faces


class HoldsPose:
    """The operator of a robot that holds its pose in a stop (an arm)."""

    def replays(self, batch) -> tuple:
        """``(stop_replay, fall_replay)`` of ``batch`` (a
        :class:`~sim2real.eval.soak.batch.SessionBatch`): ``(None, None)``."""
        return None, None

    def before_reset(self, batch, due: np.ndarray) -> None:
        """Before the envs ``due`` (bool mask) are reset: nothing."""


class LiesDown:
    """The operator of a robot that lies down, damped, in every stop (a legged robot)."""

    def replays(self, batch) -> tuple:
        """``(StopReplay(batch), FallReplay(...))``: its stops and falls replayed without the
        stop (what a stop saved it from)."""
        from sim2real.eval.soak.counterfactual import StopReplay
        from sim2real.eval.soak.fall_replay import FallReplay

        stop = StopReplay(batch)
        return stop, FallReplay(stop)

    def before_reset(self, batch, due: np.ndarray) -> None:
        """Stand the robots of ``due`` (bool mask) up (``batch.stand_up``) and count it in
        their sessions' ``stood_up``."""
        if due.any():
            batch.stand_up(due)
            for e in np.flatnonzero(due):
                batch.sessions[e].stood_up += 1


#: The soak operator's face of each robot kind, by the kind's name.
OPERATOR_OF_KIND: Faces = Faces("soak operator")
OPERATOR_OF_KIND.register("arm", HoldsPose())
OPERATOR_OF_KIND.register("legged", LiesDown())
