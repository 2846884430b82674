"""The motion clock of a phase-clocked policy: the time since its motion started, which the
runtime's floating-base tick owns and the ``motion_phase`` block reads
(:mod:`sim2real.deploy.spec.motion_blocks`).

A phase-clocked dance (rl_sar's ``RoboMimic_Deploy/phase``, RoboMimic_Deploy's ``Dance``) reads
``t / T``, ``t`` the time since the dance state was entered, ``T`` the motion's length. Both
stacks count it in policy ticks from the state's entry: rl_sar's ``RL_Sim::RunModel`` adds one
to ``episode_length_buf`` (0 from the fsm state's ``Enter``) before it computes the observation,
``t = episode_length_buf x dt x decimation`` (``rl_sdk.cpp``); RoboMimic_Deploy's ``Dance.run``
reads ``counter_step x 0.02`` and counts the step after (``policy/dance/Dance.py``). What each
stack's first tick reads is the block's ``offset`` (its reader's business); this clock reads the
RUNNING ticks before this one in the current play: 0 on the first RUNNING tick.

The runtime's dance state is RUNNING: RAMP_IN brings the robot to its home pose first, as
rl_sar's GetUp does before the dance; any other mode (a safe stop, the operator's stop, a
restart) ends the play, and the next RUNNING tick starts it at 0 again. The clock is advanced at
the start of each tick, before the supervision, from the modes the previous tick ended in.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.core.stateful import put, take


class MotionPhaseClock:
    """Each env's time since its motion started (module docstring).

    Args:
        envs: Batch size. period: The control period, s (> 0).

    Attributes:
        ticks: (envs,) int64, RUNNING ticks before this one in the current play.
        time: (envs,) float64, s, what this tick's observation reads (``ticks x period``): the
            array ``RobotState.motion_time`` is.
    """

    def __init__(self, envs: int, period: float):
        if not (np.isfinite(period) and period > 0.0):
            raise ValueError(f"period: expected s > 0, got {period!r}")
        self.period = float(period)
        self.ticks = np.zeros(envs, dtype=np.int64)
        self.time = np.zeros(envs)

    def advance(self, mode: np.ndarray) -> np.ndarray:
        """This tick's ``time`` from the modes (envs,) the previous tick ended in: an env that
        ran it RUNNING plays on one period, any other starts again at 0."""
        self.ticks[:] = np.where(np.asarray(mode) == RUNNING, self.ticks + 1, 0)
        np.multiply(self.ticks, self.period, out=self.time)
        return self.time

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """``ticks`` and ``time`` of every env, or of env ``env`` (copies)."""
        return take({"ticks": self.ticks, "time": self.time}, env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`; raises StateDictError (a field missing or of another
        shape, nothing written)."""
        put({"ticks": self.ticks, "time": self.time}, state, env)


def phase_clock_for(spec, state, period: float) -> MotionPhaseClock | None:
    """The clock of a spec with a ``motion_phase`` block (``state.motion_time`` set to its time),
    else None."""
    if not any(b.name == "motion_phase" for b in spec.observation_blocks):
        return None
    clock = MotionPhaseClock(state.q.shape[0], period)
    state.motion_time = clock.time
    return clock
