"""A hand-over between two policies (:class:`HandOver`): :meth:`Runtime.switch_policy
<sim2real.deploy.runtime.loop.Runtime.switch_policy>` swaps the runtime's policy at once and, while
any env is RUNNING, blends the outgoing policy's targets into the receiving one's over a set time.

For ``ticks`` control periods after the switch the outgoing policy still runs, on its own
observation (its spec's blocks over the same estimate), and each RUNNING env's target is
``a * received + (1 - a) * outgoing`` with ``a`` rising linearly from ``1 / (ticks + 1)`` to 1:
no step in the PD targets beyond what either policy moves in a tick plus ``1 / (ticks + 1)`` of
the gap between them. The guard and the smoother run after the blend, as on every tick; the
smoother's limits bound the command whatever the blend does. The largest tick-to-tick target
step of the hand-over is kept (:attr:`HandOver.max_target_step`) for the operator's report.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RAMP_IN, RUNNING


class HandOver:
    """The outgoing side of a hand-over.

    Args:
        policy: The outgoing policy (callable ``(envs, obs_dim) float32 -> (envs, n)``).
        spec: Its :class:`~sim2real.deploy.spec.policy_spec.PolicySpec`.
        envs, n: The runtime's envs and joints.
        ticks: Control periods of the blend (>= 1).
        target: (envs, n) the runtime's target at the switch (units of the control mode), the
            reference of the first step.

    Raises:
        ValueError: ``ticks`` < 1.
    """

    def __init__(self, policy, spec, envs: int, n: int, ticks: int, target: np.ndarray):
        if ticks < 1:
            raise ValueError(f"HandOver: ticks must be >= 1, got {ticks}")
        self.policy, self.spec, self.ticks = policy, spec, int(ticks)
        self.done = 0
        self._obs = np.zeros((envs, spec.obs_dim), dtype=np.float32)
        self._outgoing = np.zeros((envs, n))
        self._previous = np.array(target, dtype=np.float64)
        #: the largest tick-to-tick change of a RUNNING env's blended target, units of the mode
        #: (rad in position mode), over the blend
        self.max_target_step = 0.0

    @property
    def finished(self) -> bool:
        """True once the blend's last tick ran."""
        return self.done >= self.ticks

    def blend(self, target: np.ndarray, state, goal: np.ndarray, mode: np.ndarray) -> None:
        """Blend ``target`` ((envs, n), the receiving policy's after the screen) in place for the
        RUNNING envs of ``mode`` with the outgoing policy's target at ``state`` and ``goal``; a
        non-finite outgoing action leaves the receiving target as it is."""
        running = mode == RUNNING
        self.done += 1
        if running.any():
            obs = self.spec.observation(state, goal, out=self._obs)
            action = np.asarray(self.policy(obs))
            out = self.spec.action_to_target(action, state, out=self._outgoing)
            a = self.done / (self.ticks + 1)
            mixed = a * target + (1.0 - a) * out
            ok = running[:, None] & np.isfinite(mixed)
            np.copyto(target, mixed, where=ok)
            step = np.abs(target[running] - self._previous[running])
            if step.size:
                self.max_target_step = max(self.max_target_step, float(step.max()))
        self._previous[:] = target


def check_policy(spec, robot, mode: str, targets) -> None:
    """Refuse a policy's ``spec`` made for another robot than ``robot`` or another control mode
    than ``mode`` (the backend's), or one asking for no smoothing of a robot whose drives all
    follow their command (``targets``, its kind's
    :class:`~sim2real.deploy.kinds.targets.DriveTargets`).

    Raises:
        ValueError: naming the mismatch (:meth:`PolicySpec.check_robot
            <sim2real.deploy.spec.policy_spec.PolicySpec.check_robot>`'s, or the mode's).
    """
    spec.check_robot(robot)
    if spec.action.mode != mode:
        raise ValueError(
            f"policy action mode '{spec.action.mode}' differs from the backend's control "
            f"mode '{mode}'"
        )
    targets.check_smoothing(spec.action.smoothing, robot.name)


def follows_targets(spec, targets, mode: str) -> bool:
    """Whether the runtime's RUNNING envs command ``spec``'s targets as the policy emitted them
    (after the guard), not through the smoother: a PD-target robot (``targets``, its kind's
    :class:`~sim2real.deploy.kinds.targets.DriveTargets`) in position mode whose spec's
    ``action.smoothing`` is ``'none'`` or left to the robot's default
    (:class:`~sim2real.deploy.spec.policy_spec.ActionSpec`), as the policy was trained."""
    return targets.follows_policy(spec.action.smoothing, mode)


def switch_policy(runtime, policy, blend_time: float) -> None:
    """:meth:`Runtime.switch_policy <sim2real.deploy.runtime.loop.Runtime.switch_policy>`: hand
    ``runtime``'s control to ``policy``. Its spec is checked against the robot and the control
    mode; its state is reset for every env (a recurrent policy's memory; its observation is
    built afresh from its own spec's blocks, its plan built now, not in a tick); for
    ``blend_time`` s (rounded to control periods) the targets of the RUNNING envs blend from the
    outgoing policy's into its own (:class:`HandOver`); 0 s, or no env RUNNING: at once (RAMP_IN
    hands over from the home pose anyway). A hand-over still in progress is cut short: the
    policy it was leaving is dropped, the blend starts again from the current target.

    What the new policy reads beyond the estimate goes with it (:func:`carry_inputs`): its
    image input's camera stage (the backend's camera, built again for another image block, none
    for a policy without one) and a phase-clocked policy's motion clock, started again (its
    first RUNNING tick reads 0, as rl_sar's fsm state's ``Enter`` resets
    ``episode_length_buf``).

    Raises:
        ValueError: a spec for another robot or control mode, a negative ``blend_time``, an
            image block the backend's camera does not serve, a motion phase on a robot whose
            tick keeps no motion clock (nothing changed).
    """
    if not blend_time >= 0:
        raise ValueError(f"switch_policy: blend_time must be >= 0 s, got {blend_time}")
    check_policy(policy.spec, runtime.robot, runtime.mode_name, runtime.targets)
    carry = carry_inputs(runtime, policy.spec)  # checked before anything changes
    ticks = int(round(blend_time / runtime.dt))
    outgoing, spec = runtime.policy, runtime.spec
    runtime.handover = None
    if ticks > 0 and (runtime.mode == RUNNING).any():
        n = runtime.robot.n_joints
        runtime.handover = HandOver(outgoing, spec, runtime.envs, n, ticks, runtime.target)
    runtime.policy, runtime.spec = policy, policy.spec
    carry()
    runtime.follows_targets = follows_targets(policy.spec, runtime.targets, runtime.mode_name)
    if not runtime.follows_targets:  # the smoother shapes every env's targets again
        runtime.smoother.follow_envs.fill(False)
    obs = runtime._obs  # noqa: SLF001 - the runtime's own room
    if obs.shape[1] != runtime.spec.obs_dim:
        runtime._obs = obs = np.zeros((runtime.envs, runtime.spec.obs_dim), dtype=np.float32)
    runtime.spec.observation(runtime.state, runtime.goal, out=obs)
    runtime._reset_policy(np.ones(runtime.envs, dtype=bool))  # noqa: SLF001


def carry_inputs(runtime, spec):
    """Check what ``spec`` reads beyond the estimate against ``runtime`` and return the
    function that hands it over (:func:`switch_policy`): the camera stage and the motion clock.

    Raises:
        ValueError: an image block the backend's camera (``backend.camera_source``) does not
            serve (none, or another camera, kind or frame size), a ``motion_phase`` block on a
            runtime whose base tick keeps no motion clock (a fixed base).
    """
    from sim2real.deploy.core.modes import RUNNING as running_mode
    from sim2real.deploy.core.phase_clock import phase_clock_for
    from sim2real.deploy.runtime.camera import camera_stage

    images = getattr(spec, "images", ())
    current = runtime.cameras
    rebuild = bool(images) and (current is None or tuple(current.blocks) != tuple(images))
    if rebuild:
        source = getattr(runtime.backend, "camera_source", None)
        group = getattr(source, "sources", None)  # several cameras: the backend's by name
        for block in images:
            own = source if len(images) == 1 else (group or {}).get(block.camera)
            served = getattr(own, "block", None)
            if own is None or (
                served is not None
                and (served.camera, served.kind, tuple(served.shape))
                != (block.camera, block.kind, tuple(block.shape))
            ):
                what = (
                    "none" if own is None else f"'{served.camera}' ({served.kind}, {served.shape})"
                )
                raise ValueError(
                    f"switch_policy: the policy's {block.kind} camera '{block.camera}' "
                    f"{tuple(block.shape)} is not the backend's camera ({what}): attach it for "
                    "this policy"
                )
    tick = runtime.base_tick
    phased = any(b.name == "motion_phase" for b in spec.observation_blocks)
    if phased and not hasattr(tick, "phase_clock"):
        raise ValueError(
            "switch_policy: the policy reads a motion_phase; this robot's tick keeps no motion "
            "clock (a floating base's does)"
        )

    def carry() -> None:
        if not images:
            runtime.cameras = None
        elif rebuild:
            runtime.cameras = camera_stage(spec, runtime.envs, runtime.robot, runtime.backend)
        # the fused estimate-and-observe call only without a camera stage to feed (as built)
        fused = runtime._compiled is not None and tick.fusable  # noqa: SLF001 - the runtime's room
        runtime._fused = fused and runtime.cameras is None  # noqa: SLF001
        if phased:
            if tick.phase_clock is None:
                tick.phase_clock = phase_clock_for(spec, runtime.state, runtime.dt)
            clock = tick.phase_clock
            # the next RUNNING tick's advance makes it 0: the new motion's first tick
            clock.ticks[:] = np.where(runtime.mode == running_mode, -1, 0)
            clock.time.fill(0.0)

    return carry


class RampIn:
    """A slow RAMP_IN (:meth:`Runtime.ramp_in <sim2real.deploy.runtime.loop.Runtime.ramp_in>`):
    for ``ticks`` control periods the position target of the envs of ``envs`` still in RAMP_IN
    moves along a straight line from ``start`` to ``home`` (the Unitree bring-up's ramp, and
    unitree_rl_gym's move to the default pose), instead of stepping to home at once; the
    smoother and the guard run after it as on every tick.

    Args:
        start: (envs, n) rad, where each env's ramp begins (its pose at the reset).
        home: (n,) rad. envs: (envs,) bool. ticks: control periods of the ramp (>= 1).
        speeds: (n,) bool, the velocity-driven joints (a wheel: its target is a speed, its angle
            no place to ramp from): held at their home entry, 0 rad/s. None: none.
        running: the envs ramp while RUNNING instead (the policy's targets replaced) and stay
            at home once there, for as long as they stay RUNNING: the policy off, the PD loop
            holding the home pose (unitree_rl_gym ``deploy/deploy_real/deploy_real.py``,
            ``move_to_default_pos`` then ``default_pos_state``; a clip's end,
            :mod:`sim2real.deploy.rig.after_clip`).
    """

    def __init__(
        self,
        start: np.ndarray,
        home: np.ndarray,
        envs: np.ndarray,
        ticks: int,
        speeds: np.ndarray | None = None,
        running: bool = False,
    ):
        self.start = np.array(start, dtype=np.float64)
        self.home = np.asarray(home, dtype=np.float64)
        if speeds is not None:
            self.start[:, speeds] = self.home[speeds]
        self.envs, self.ticks, self.done = np.asarray(envs, dtype=bool).copy(), max(1, ticks), 0
        self.mode, self.hold = (RUNNING, True) if running else (RAMP_IN, False)

    def shape(self, target: np.ndarray, mode: np.ndarray) -> bool:
        """Write the ramp's target of this tick into ``target`` ((envs, n), rad) for the envs
        still in RAMP_IN (RUNNING with ``running``); True once the ramp has ended (its last
        tick, or no env left in it; with ``running``, only the latter: home holds)."""
        self.done += 1
        a = min(1.0, self.done / self.ticks)
        ramp = self.envs & (mode == self.mode)
        if ramp.any():
            target[ramp] = self.start[ramp] + a * (self.home - self.start[ramp])
        return (a >= 1.0 and not self.hold) or not ramp.any()
