"""The parts of a :class:`~sim2real.deploy.spec.policy_spec.PolicySpec`: one observation block
(:class:`ObservationBlock`, its clip defaults) and the action mapping (:class:`ActionSpec`, its
smoothing values). The normalization and the action convention are
:mod:`sim2real.deploy.spec.policy_spec`'s module docstring.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim2real.deploy.spec.height_scan import HeightScanPattern

#: Default observation clip (in normalized units); generous, since values are already ~[-1, 1].
#: The default of our own policies' blocks (:class:`ObservationBlock`); a spec file's block
#: without a clip is not clipped (:data:`UNCLIPPED`).
DEFAULT_CLIP = 5.0
#: The clip of a value nothing clips (a spec file's block or action without ``clip``, a foreign
#: contract's unclipped term): JSON has no infinity, and no observation in SI units (rad, rad/s,
#: m/s) nor action reaches it, so it never binds.
UNCLIPPED = 1.0e6

#: ``ActionSpec.smoothing``'s values; ``''``: the robot's default (see there).
SMOOTHING = ("", "none", "jerk_limited")


@dataclass(frozen=True)
class ObservationBlock:
    """One block of the observation vector.

    Attributes:
        name: The block kind (a kind registered in :mod:`sim2real.deploy.spec.kinds`).
        size: Number of entries it contributes.
        scale: Per-entry divisor (physical maximum), length ``size``; finite and nonzero (a
            negative scale flips the entry's sign, as some policies read their gait clock).
        offset: Per-entry offset, length ``size``.
        clip: Symmetric clip after normalization.
        joints: Joint indices it reads (joint blocks only), in order.
        period: ``gait_phase``: the gait clock's period, s (> 0); ``motion_phase``: the
            motion's length ``T``, s (> 0; :mod:`sim2real.deploy.spec.motion_blocks`); 0 for
            other blocks.
        components: The vector kinds' and ``gait_phase``'s blocks only: the entries of the raw
            vector it reads, in order (``(2,)``: the yaw rate of ``velocity_command``;
            ``(1, 3, 0, 2)``: a two-foot clock ``cos p, cos(p + pi), sin p, sin(p + pi)``);
            empty: the kind's own (a vector's three; ``gait_phase``: ``sin p, cos p``).
        stand_below: ``gait_phase`` only: the clock stops while the velocity command's
            ``|(vx, vy)|`` (m/s) and ``|yaw rate|`` (rad/s) are both below it, every foot held at
            ``stand_phase``, and restarts at phase 0 (:func:`sim2real.deploy.spec.kernel.
            gait_clock`); 0: it never stops.
        stand_phase: ``gait_phase`` only: the phase every foot is held at while standing, rad.
        scan: ``height_scan`` only: where it measures the terrain
            (:class:`sim2real.deploy.spec.height_scan.HeightScanPattern`); None for other blocks.
    """

    name: str
    size: int
    scale: tuple[float, ...]
    offset: tuple[float, ...]
    clip: float = DEFAULT_CLIP
    joints: tuple[int, ...] = ()
    period: float = 0.0
    components: tuple[int, ...] = ()
    stand_below: float = 0.0
    stand_phase: float = 0.0
    scan: HeightScanPattern | None = None


@dataclass(frozen=True)
class ActionSpec:
    """How the policy output maps to a target.

    Attributes:
        mode: 'position' (rad), 'velocity' (rad/s) or 'torque' (N m).
        size: Number of actions (= joints).
        scale: Per-joint scale, length ``size`` (units of the mode per unit action).
        offset: Per-joint offset, length ``size``.
        clip: The action is clipped to ``[-clip, clip]`` before mapping.
        reference: 'absolute' (``offset + scale * a``) or 'current' (position mode only:
            ``q + scale * a``).
        joints: The joint each output of the graph drives, in output order (indices into
            ``joint_names``, each at most once); empty: output ``i`` drives joint ``i``. The
            policy (:class:`sim2real.deploy.policy.onnx_policy.OnnxPolicy`) scatters its output into
            ``joint_names`` order, so ``scale``, ``offset`` and the runtime's ``last_action``
            are in ``joint_names`` order. Fewer outputs than joints: a policy over part of the
            robot (:meth:`PolicySpec.on_robot`); a joint no output drives has action 0, its
            target is its ``offset`` (position mode: held at that pose, as Unitree's deploy
            code holds the joints its policies do not drive).
        smoothing: How the targets reached the drives in training, where the robot's drives
            run a PD law on position targets (a PD-target robot kind): ``'none'``, each target
            as the policy emitted it (legged_gym, Isaac Lab, mjlab and their deploy loops: a
            target is a torque request); ``'jerk_limited'``, through the runtime's Ruckig
            stage within the robot's velocity, acceleration and jerk limits (the toolkit's own
            training, which runs the runtime); ``''`` (left out), the robot's default:
            ``'none'`` for a PD-target robot, else ``'jerk_limited'``. The runtime reproduces
            it. Other robots' commands are always jerk-limited (the smoother is their safety
            stage): ``'none'`` there is refused when the policy meets the robot.
    """

    mode: str
    size: int
    scale: tuple[float, ...]
    offset: tuple[float, ...]
    clip: float = 1.0
    reference: str = "absolute"
    joints: tuple[int, ...] = ()
    smoothing: str = ""

    @property
    def outputs(self) -> int:
        """The graph's action outputs: ``len(joints)`` when set, else ``size``."""
        return len(self.joints) if self.joints else self.size

    @property
    def driven(self) -> tuple[int, ...]:
        """The joints some output drives, ascending (every joint when ``joints`` is empty)."""
        return tuple(sorted(self.joints)) if self.joints else tuple(range(self.size))
