"""A policy's own loop on a bare plant: one MuJoCo model with torque actuators under the PD law at
every physics step (:class:`BarePlant`), the true base judged as the soak judges it (a fall:
:func:`true_fall`; upright at a stop: :func:`true_upright`; a joint past its hard limit:
:func:`past_hard_limit`) and one run's outcome (:class:`Run`). The other stacks' own loops
(:mod:`sim2real.stacks.loops`), the push benchmark (``bench/push_loops.py``) and the soak's
own-loop reference of a dance (:mod:`sim2real.eval.soak.own_loop_limits`) run on it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from sim2real.deploy.core.attitude import projected_gravity
from sim2real.deploy.estimation.fall import FALL_TILT
from sim2real.deploy.monitors.estimation import TRUE_FALL_HEIGHT
from sim2real.eval.soak.falls import upright

#: A run's cause when a tick of our runtime raised (a safe stop Ruckig could not plan): the run
#: ends there and the table counts it apart, not as a stop.
STOP_RAISED = "raised"
#: s a run may spend in RAMP_IN before walking (our runtime; a fall if it never walks)
RAMP_TIMEOUT = 10.0
#: s after a push's start past which a tick counts as walking undisturbed (``Run.quiet_ticks``):
#: our choice, twice the second over which the soak judges the estimate after a push.
QUIET_AFTER_PUSH = 2.0


@dataclass
class Run:
    """One run's outcome.

    Attributes:
        fell_at: s on the loop's clock at the fall (None: no fall). cause: what ended it
            (``"fall"`` for a true fall in a loop without stops; ours: the stop's cause, or
            ``"fall"`` seen by the truth first). walked: s walked (ours: RUNNING). pushes: the
            pushes applied (their times, s).
        ticks, intervened: RUNNING ticks, and those on which the guard or the smoother changed
            a command (ours). checks: ticks per intervention check (ours).
        upright_stop: ours: the run ended by a stop while the truth had the robot upright
            (:func:`true_upright`).
        after_push: ours: ``PushResponse.summary()`` (None without a judged push).
        past_limit: ticks (RUNNING, ours) whose end found a joint of the true state past its
            hard position limit (:func:`past_hard_limit`), in either loop: what a guard that
            keeps the joints inside their range would have had to prevent.
        quiet_ticks, quiet_intervened: ours: the RUNNING ticks before the first push or more
            than ``QUIET_AFTER_PUSH`` after the last one's start, and those on which the guard
            or the smoother changed a command (the interventions of undisturbed walking).
    """

    fell_at: float | None = None
    cause: str | None = None
    walked: float = 0.0
    pushes: list = field(default_factory=list)
    ticks: int = 0
    intervened: int = 0
    checks: dict = field(default_factory=dict)
    upright_stop: bool = False
    after_push: dict | None = None
    past_limit: int = 0
    quiet_ticks: int = 0
    quiet_intervened: int = 0


class BarePlant:
    """One bare MuJoCo model with torque actuators (``robot.plant_model("torque")``) under the own
    loops' PD law ``tau = kp (target - q) - kd dq`` at every physics step: the plant of
    :class:`~sim2real.deploy.rig.own_loop.OwnLoop` here (its true state, ``write``, ``advance``)
    and of the foreign stacks' loops. ``gains``: (kp, kd, the first target), (n,) each."""

    def __init__(self, robot, m: mujoco.MjModel, d: mujoco.MjData, gains):
        self.m, self.d = m, d
        self.kp, self.kd, self.target = gains
        self.qo, self.vo = robot.qpos_offset, robot.qvel_offset
        self.decimation = round(robot.control_period / m.opt.timestep)

    def true_position(self) -> np.ndarray:
        """(1, n) rad, the joints' angles (a view)."""
        return self.d.qpos[None, self.qo :]

    def true_velocity(self) -> np.ndarray:
        """(1, n) rad/s, the joints' speeds (a view)."""
        return self.d.qvel[None, self.vo :]

    def true_base_state(self, out: np.ndarray | None = None) -> np.ndarray:
        """(1, 13) the free joint's ``qpos[:7]`` and ``qvel[:6]`` (as the plant's)."""
        out = np.empty((1, 13)) if out is None else out
        out[0, :7], out[0, 7:] = self.d.qpos[:7], self.d.qvel[:6]
        return out

    def write(self, target: np.ndarray) -> None:
        """The PD's target, (n,) or (1, n) rad."""
        self.target = np.asarray(target).reshape(-1)

    def advance(self) -> None:
        """One control period: the PD law and ``mj_step`` at each physics step."""
        m, d, qo, vo = self.m, self.d, self.qo, self.vo
        kp, kd, target = self.kp, self.kd, self.target
        for _ in range(self.decimation):
            d.ctrl[:] = kp * (target - d.qpos[qo:]) - kd * d.qvel[vo:]
            mujoco.mj_step(m, d)


def _tilt(quaternion: np.ndarray) -> float:
    """rad, the base's tilt from upright (base-to-world ``quaternion`` w, x, y, z)."""
    up = -projected_gravity(np.asarray(quaternion, dtype=float))[2]
    return float(np.arccos(np.clip(up, -1.0, 1.0)))


def true_fall(robot, position_z: float, quaternion: np.ndarray) -> bool:
    """Whether the true base has fallen: below ``TRUE_FALL_HEIGHT`` of the standing height or
    tilted past the robot's fall tilt (rad; default ``FALL_TILT``), as the soak counts a fall."""
    low = TRUE_FALL_HEIGHT * robot.config.base.standing_height
    if not (np.isfinite(position_z) and position_z >= low):
        return True
    return _tilt(quaternion) > (robot.config.safety.fall_tilt or FALL_TILT)


def past_hard_limit(robot, q: np.ndarray) -> bool:
    """Whether a joint of ``q`` (n,) rad lies past its hard position limit (robot.toml's
    ``position_limit``; a continuous joint never does)."""
    return bool(((q > robot.position_upper) | (q < robot.position_lower)).any())


def quiet(t: float, pushes: list) -> bool:
    """Whether time ``t`` (s) is before the first of ``pushes`` (their start times, s) or more
    than ``QUIET_AFTER_PUSH`` after the last one before it."""
    return not pushes or t - pushes[-1] > QUIET_AFTER_PUSH


def true_upright(robot, position_z: float, quaternion: np.ndarray, vz: float = 0.0) -> bool:
    """Whether the true base is upright as the soak's ``false_fall_stops`` judges a stop
    (:func:`sim2real.eval.soak.falls.upright`; ``vz``: m/s, the true base's vertical
    velocity)."""
    limit = robot.config.safety.fall_tilt or FALL_TILT
    standing = robot.config.base.standing_height
    return bool(upright(_tilt(quaternion), position_z, vz, limit, standing))


def judge_tick(run: Run, walk, robot, d, tick: int, period: float, schedule, pushed) -> bool:
    """After an own loop's control tick ``tick`` (1-based, of ``period`` s) on the true state
    ``d`` (MjData):
    ``run.walked`` and ``walk.ticks`` set to ``tick``, a joint past its hard limit counted, and
    the pushes of ``schedule`` (a ``DomainPushes``, or None) applied through ``pushed``. Returns
    True, with ``run.fell_at`` (s) and ``run.cause`` set, when the true base fell or the state is
    no longer finite: the loop ends there (then ``run.walked *= period`` as at any end)."""
    run.walked = walk.ticks = tick
    run.past_limit += past_hard_limit(robot, d.qpos[robot.qpos_offset :])
    if true_fall(robot, d.qpos[2], d.qpos[3:7]) or not np.isfinite(d.qpos).all():
        run.fell_at, run.cause = tick * period, "fall"
        return True
    if schedule is not None:
        schedule(walk, pushed)
    return False


def bare_plant(robot, gains) -> BarePlant:
    """A :class:`BarePlant` of ``robot`` at its home pose, at rest, under ``gains`` (kp, kd,
    the first target)."""
    m = robot.plant_model("torque")
    d = mujoco.MjData(m)
    d.qpos[robot.qpos_offset :] = robot.home
    mujoco.mj_forward(m, d)
    return BarePlant(robot, m, d, gains)
