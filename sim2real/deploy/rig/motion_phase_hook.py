"""``deploy-run``'s figures of a phase-clocked policy (a ``motion_phase`` block): how much of its
motion it played and how closely the joints followed the targets it set.

A phase-clocked dance (rl_sar's RoboMimic charleston) reads no clip, so there is no reference to
judge its joints against; what a run of it can be compared on is what its own runtime's loop
gives too (``sim2real.stacks.loops.robomimic_dance``): the share of the motion's length ``T``
played before a stop, the stops during it, and the joints' error against the policy's targets (rad
RMS: each RUNNING tick's true joint angles, after the tick's physics, against the target that tick
commanded, while the motion clock is below ``T``; the plant's truth in simulation, the estimate
otherwise). The motion clock is the runtime's
(:class:`~sim2real.deploy.core.phase_clock.MotionPhaseClock`, its floating-base tick's).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.rig.hooks import RunHook


class MotionPhaseHook(RunHook):
    """The figures of the module docstring for every env of ``rig`` (its runtime's tick has a
    ``phase_clock``); ``length``: the motion's ``T``, s (the ``motion_phase`` block's period)."""

    name = "motion_phase"

    def __init__(self, rig, length: float):
        envs, n = rig.envs, rig.robot.n_joints
        self.rig, self.length = rig, float(length)
        self.sq = np.zeros((envs, n))
        self.ticks = np.zeros(envs, dtype=np.int64)  # judged ticks
        self.best = np.zeros(envs)  # s, the furthest a play reached
        self.plays = np.zeros(envs, dtype=np.int64)
        self.stopped = np.zeros(envs, dtype=np.int64)  # plays a stop ended before T
        self._playing = np.zeros(envs, dtype=bool)

    def after_tick(self, r) -> None:
        clock = r.base_tick.phase_clock
        running = r.mode == RUNNING
        self.plays += running & (clock.ticks == 0)
        # a play that ends (any mode but RUNNING) before T: a stop cut it short
        self.stopped += self._playing & ~running
        t = clock.time
        played = running & (t < self.length)
        self.best = np.where(
            running, np.maximum(self.best, np.minimum(t + clock.period, self.length)), self.best
        )
        self._playing = played & (t + clock.period < self.length)
        if not played.any():
            return
        sim = self.rig.backend if self.rig.simulated else None
        q = sim.true_position() if sim is not None else r.state.q
        err = (q - r.target) ** 2
        self.sq[played] += err[played]
        self.ticks[played] += 1

    def summary(self) -> dict:
        """``length_s``, ``plays``, ``completed`` (share of ``T`` the furthest play reached, the
        worst env), ``stopped`` (plays a stop ended before ``T``), ``joint_rms_rad`` (against the
        targets, every joint and judged tick) and ``ticks`` (judged)."""
        ticks = int(self.ticks.sum())
        n = self.sq.shape[1]
        return {
            "length_s": self.length,
            "plays": int(self.plays.sum()),
            "completed": float(self.best.min() / self.length),
            "stopped": int(self.stopped.sum()),
            "joint_rms_rad": float(np.sqrt(self.sq.sum() / (n * ticks))) if ticks else None,
            "ticks": ticks,
        }

    def contribute(self, report: dict) -> None:
        report["motion_phase"] = self.summary()


def motion_phase_hook(rig) -> MotionPhaseHook | None:
    """The hook of a rig whose runtime has a motion clock (its policy's ``motion_phase`` block's
    period the motion's length), else None."""
    if getattr(rig.runtime.base_tick, "phase_clock", None) is None:
        return None
    block = next(b for b in rig.runtime.spec.observation_blocks if b.name == "motion_phase")
    return MotionPhaseHook(rig, block.period)
