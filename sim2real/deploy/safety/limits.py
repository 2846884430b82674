"""The guard's position-limit checks: ``soft_limit`` and ``hard_limit``.

``soft_limit``: a target position beyond the soft limit (``soft_limit_fraction`` of the range,
90 % by default) is clamped to it; in velocity and torque mode the estimate inside the soft band
is counted (a warning). A position target of a robot whose drives run a PD law on it
(``pd_targets``: a floating base) is not clamped: it is a torque request (``kp (target - q)``;
legged policies command past the joint range by design, legged_gym trains without any bound on
the targets), judged by its predicted consequence instead (``pd_barrier``,
:mod:`sim2real.deploy.safety.pd_barrier`). ``hard_limit``: the target, the estimate or (velocity
mode) the predicted position beyond the hard limit: :attr:`SafetyGuard.hard_violation
<sim2real.deploy.safety.guard.SafetyGuard.hard_violation>` is set and the runtime makes a safe stop
(a PD-target robot's *target* has no hard bound).

A floating-base robot's *estimate* past a hard limit stops it when it has been more than
``LEGGED_HARD_LIMIT_TOLERANCE`` past for longer than ``LEGGED_HARD_LIMIT_BOUNCE``, or past at all
for longer than ``LEGGED_HARD_LIMIT_DURATION``; an arm's stops at once. For a
walking robot every stop is a fall (it lies down, damped): an estimate a few hundredths of a radian
past a hip's limit at the end of a stride (the soak's heavier links or stiffer joints carry a swing
a little further; the estimate's noise does the rest) is not worth dropping a 50 kg robot, nor is a
joint that a stumble swings into its stop and that bounces off it within a few ticks (the impact
has happened; a stop adds a fall to it); a joint driven into its stop and held there is, and so is
an estimate far past it that stays there (a broken encoder or joint). The soak's violation monitor
still counts every true tick past the limit.

Each is a :class:`sim2real.deploy.safety.check.GuardCheck`: its numpy reference and its compiled per-env
function do the same operations in the same order. Units: rad.
"""

from __future__ import annotations

import numba
import numpy as np

from sim2real.deploy.kernels import np_max, np_min
from sim2real.deploy.safety.check import (
    CLAMP,
    FIRED,
    INSPECT,
    LOWER,
    POSITION,
    PREDICTED,
    SOFT_LOWER,
    SOFT_UPPER,
    UPPER,
    VELOCITY,
    GuardCheck,
)

#: Rows of the hard-limit check's constants: the bounds of a position target (hard limits
#: widened by the guard's target tolerance; infinite for a floating base), how far past a hard
#: limit the estimate may be (rad), for how many ticks past at all, and for how many ticks
#: farther than that (all 0 for an arm: a stop at once).
TARGET_LOWER, TARGET_UPPER, TOLERANCE, DURATION, BOUNCE = 0, 1, 2, 3, 4
#: A floating-base robot: the estimate this far past a hard limit stops it once past for longer
#: than ``LEGGED_HARD_LIMIT_BOUNCE``, rad. Our choice: 0.1 rad (5.7 deg), above the 0.02-0.06 rad
#: the H1's hips' estimates crossed by at the end of a stride in the soak's randomized dynamics,
#: below the few tenths of a radian between a humanoid's or a quadruped's joint range in its MJCF
#: and its mechanical stop.
LEGGED_HARD_LIMIT_TOLERANCE = 0.1
#: A floating-base robot: the estimate past a hard limit (by less than the tolerance) this long
#: stops it, s. Our choice: 1 s, longer than one gait cycle of the shipped legged policies (the
#: H1's and H1-2's 0.8 s, unitree_rl_gym's deploy_mujoco.py ``period``; the Go2's trot is
#: shorter): an estimate past the limit for a stride comes back within it, a joint driven into
#: its stop and held there does not.
LEGGED_HARD_LIMIT_DURATION = 1.0
#: A floating-base robot: the estimate more than ``LEGGED_HARD_LIMIT_TOLERANCE`` past a hard limit
#: for longer than this stops it, s. Our choice: 0.1 s (5 ticks at the shipped legged robots'
#: 50 Hz), longer than a joint's bounce off its stop: a stumble swung the H1's hip roll into its
#: stop at about 10 rad/s, 0.09 rad past it in MuJoCo's soft limit (the estimate 0.11) and back
#: inside within 3 ticks (1-hour soak, seed 4320). Counted while farther than the tolerance, not
#: while past at all: the H1-2's ankle, past by a little for 0.1 s as it crouched to catch a
#: stumble, then 0.105 rad past for 2 ticks (seed 20, 55.6 s of its training domain), stood when
#: the soak replayed it without the stop (:mod:`sim2real.eval.soak.counterfactual`).
LEGGED_HARD_LIMIT_BOUNCE = 0.1


#: Row of the soft-limit check's constants: 1.0 where it clamps position targets, 0.0 where a
#: position target is a PD loop's torque request (:mod:`sim2real.deploy.safety.pd_barrier`).
CLAMPS = 0


@numba.njit(cache=True, nogil=True, _nrt=False)
def soft_limit_kernel(stage, e, out, q, dq, commanded, has_commanded, g, own) -> int:
    """:class:`SoftLimit`'s compiled share (signature of :class:`GuardCheck`)."""
    n = out.shape[1]
    lim = g.lim
    soft = False
    if stage == INSPECT:
        if g.mode == POSITION:
            for j in range(n):
                t = out[e, j]
                if own[CLAMPS, j] == 0.0:  # a PD joint's target: the PD barrier's
                    continue
                if t < lim[SOFT_LOWER, j] or t > lim[SOFT_UPPER, j]:
                    soft = True
        else:
            for j in range(n):
                if q[e, j] > lim[SOFT_UPPER, j] or q[e, j] < lim[SOFT_LOWER, j]:
                    soft = True
    elif stage == CLAMP and g.mode == POSITION:
        for j in range(n):
            if own[CLAMPS, j] != 0.0:
                out[e, j] = np_min(np_max(out[e, j], lim[SOFT_LOWER, j]), lim[SOFT_UPPER, j])
    return FIRED if soft else 0


class SoftLimit(GuardCheck):
    """Position mode: a target past the soft limit is clamped to it (not a PD-target robot's:
    :mod:`sim2real.deploy.safety.pd_barrier` judges those by their consequence). Velocity and
    torque mode: the estimate inside the soft band (a warning; nothing changed)."""

    name = "soft_limit"
    what = "a position target clamped into the soft joint limits"
    kernel = soft_limit_kernel

    def constants(self, guard) -> np.ndarray:
        """Row ``CLAMPS``: 0.0 on a joint whose position targets drive a PD loop, else 1.0
        (:meth:`~sim2real.deploy.kinds.targets.DriveTargets.soft_clamp_row`)."""
        return guard.targets.soft_clamp_row()

    def reference(self, stage, g, out, q, dq, commanded):
        mask = g._mask
        clamps = g.targets.follows  # (n,) the joints whose position targets are clamped
        if stage == INSPECT:
            if g.mode == "position":
                np.logical_or(out < g.soft_lower, out > g.soft_upper, out=mask)
                mask &= clamps
            else:
                np.logical_or(q > g.soft_upper, q < g.soft_lower, out=mask)
            return mask.any(axis=1), None
        if stage == CLAMP and g.mode == "position":
            clamped = np.minimum(np.maximum(out, g.soft_lower), g.soft_upper)
            np.copyto(out, clamped, where=clamps)
        return None, None


@numba.njit(cache=True, nogil=True, _nrt=False)
def _run_longer(ticks, e, on, limit) -> bool:
    """Count env ``e``'s run of consecutive ticks with ``on`` in ``ticks`` (envs,) (reset to 0
    when ``on`` is False) and return whether it is longer than ``limit`` ticks."""
    ticks[e] = ticks[e] + 1 if on else 0
    return ticks[e] > limit


@numba.njit(cache=True, nogil=True, _nrt=False)
def hard_limit_kernel(stage, e, out, q, dq, commanded, has_commanded, g, own) -> int:
    """:class:`HardLimit`'s compiled share (signature of :class:`GuardCheck`)."""
    n = out.shape[1]
    lim = g.lim
    crossed = False
    if stage == INSPECT:
        past = False
        far = False
        for j in range(n):
            over = np_max(lim[LOWER, j] - q[e, j], q[e, j] - lim[UPPER, j])
            if over > 0.0:
                past = True
                if over > own[TOLERANCE, j]:
                    far = True
        if _run_longer(g.beyond_ticks, e, past, own[DURATION, 0]):
            crossed = True
        if _run_longer(g.far_ticks, e, far, own[BOUNCE, 0]):
            crossed = True
        if g.mode == POSITION:
            for j in range(n):
                t = out[e, j]
                if t < own[TARGET_LOWER, j] or t > own[TARGET_UPPER, j]:
                    crossed = True
    elif stage == PREDICTED and g.mode == VELOCITY:
        for j in range(n):
            p = g.pred[e, j]
            if p < lim[LOWER, j] or p > lim[UPPER, j]:
                crossed = True
    return FIRED if crossed else 0


class HardLimit(GuardCheck):
    """The estimate past a hard limit (a floating base's: more than its tolerance past once
    past for longer than a bounce, or past longer than its duration; module docstring), a
    position target past it (a floating base's targets are clamped instead: their bounds are
    infinite) or, in velocity mode, the predicted position: a hard violation (the runtime's safe
    stop)."""

    name = "hard_limit"
    what = "the estimate or a target past a hard limit (a safe stop)"
    stops = True
    kernel = hard_limit_kernel

    def constants(self, guard) -> np.ndarray:
        n = guard.robot.n_joints
        tolerance, ticks, bounce = guard.targets.hard_limit_rows(
            n,
            LEGGED_HARD_LIMIT_TOLERANCE,
            round(LEGGED_HARD_LIMIT_DURATION / guard.dt),
            round(LEGGED_HARD_LIMIT_BOUNCE / guard.dt),
        )
        return np.array(
            [
                guard._target_lower,
                guard._target_upper,
                tolerance,
                ticks,
                bounce,
            ],
            dtype=np.float64,
        )

    def reference(self, stage, g, out, q, dq, commanded):
        mask = g._mask
        if stage == INSPECT:
            own = self.constants(g)
            over = np.maximum(g.lower - q, q - g.upper)
            past = (over > 0.0).any(axis=1)
            far = (over > own[TOLERANCE]).any(axis=1)
            g.beyond_ticks[:] = np.where(past, g.beyond_ticks + 1, 0)
            g.far_ticks[:] = np.where(far, g.far_ticks + 1, 0)
            crossed = past & (g.beyond_ticks > own[DURATION, 0])
            crossed |= g.far_ticks > own[BOUNCE, 0]
            if g.mode == "position":
                np.logical_or(out < g._target_lower, out > g._target_upper, out=mask)
                crossed |= mask.any(axis=1)
            return crossed, None
        if stage == PREDICTED and g.mode == "velocity":
            np.logical_or(g._pred < g.lower, g._pred > g.upper, out=mask)
            return mask.any(axis=1), None
        return None, None
