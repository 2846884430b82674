"""The motion clock of a phase-clocked policy: the time since its motion started, which the
runtime owns and the ``motion_phase`` block reads (:mod:`sim2real.deploy.spec.motion_blocks`).

A phase-clocked dance (rl_sar's ``RoboMimic_Deploy/phase``, RoboMimic_Deploy's ``Dance``) reads
``t / T``, ``t`` the time since the dance state was entered, ``T`` the motion's length. Both
stacks count it in policy ticks from the state's entry: rl_sar's ``RL_Sim::RunModel`` adds one
to ``episode_length_buf`` (reset to 0 in the fsm state's ``Enter``) before it computes the
observation, ``t = episode_length_buf x dt x decimation`` (``rl_sdk.cpp``); RoboMimic_Deploy's
``Dance.run`` reads ``counter_step x 0.02`` and counts the step after (``policy/dance/Dance.py``).
What each stack's first tick reads is the block's ``offset`` (the reader's business); here the
clock reads 0 on the first RUNNING tick and one control period more on each RUNNING tick after.

The runtime's dance state is RUNNING: the clock starts on an env's first RUNNING tick (RAMP_IN
brings the robot to its home pose first, as rl_sar's GetUp does before the dance), and any other
mode (a safe stop, the operator's stop) ends the play: the next RUNNING tick starts it again at 0.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING


class MotionPhaseClock:
    """Each env's time since its motion started (module docstring).

    Args:
        envs: Batch size. period: The control period, s (> 0).

    Attributes:
        ticks: (envs,) int64, RUNNING ticks before this one in the current play; -1: not
            playing (the next RUNNING tick is the first).
        time: (envs,) float64, s, what this tick's observation reads (``ticks x period``; 0
            while not playing): ``RobotState.motion_time``.
    """

    def __init__(self, envs: int, period: float):
        if not (np.isfinite(period) and period > 0.0):
            raise ValueError(f"period: expected s > 0, got {period!r}")
        self.period = float(period)
        self.ticks = np.full(envs, -1, dtype=np.int64)
        self.time = np.zeros(envs)

    def advance(self, mode: np.ndarray) -> np.ndarray:
        """This tick's time (``time``) from the envs' modes (envs,) now: a RUNNING env's clock
        moves one tick on (its first RUNNING tick reads 0), any other stops (reads 0)."""
        running = np.asarray(mode) == RUNNING
        self.ticks[:] = np.where(running, self.ticks + 1, -1)
        self.time[:] = np.maximum(self.ticks, 0) * self.period
        return self.time

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """``ticks`` and ``time`` of every env, or of env ``env`` (copies)."""
        pick = slice(None) if env is None else env
        return {"ticks": np.array(self.ticks[pick]), "time": np.array(self.time[pick])}

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`.

        Raises:
            ValueError: a field missing or of another shape (naming it).
        """
        pick = slice(None) if env is None else env
        for name in ("ticks", "time"):
            if name not in state:
                raise ValueError(f"motion phase clock: field '{name}' missing")
            value = np.asarray(state[name])
            if value.shape != np.shape(getattr(self, name)[pick]):
                raise ValueError(
                    f"motion phase clock: field '{name}': expected shape "
                    f"{np.shape(getattr(self, name)[pick])}, got {value.shape}"
                )
            getattr(self, name)[pick] = value


def phase_clock_for(spec, envs: int, period: float) -> MotionPhaseClock | None:
    """The clock of a spec with a ``motion_phase`` block, else None."""
    if not any(b.name == "motion_phase" for b in spec.observation_blocks):
        return None
    return MotionPhaseClock(envs, period)
