"""Fall detection of a floating-base (legged) robot, from what the robot itself measures.

A robot has fallen when its base is tilted past ``safety.fall_tilt`` (rad, the angle between the
base's z axis and the world's up, from the attitude filter's projected gravity) or when, with a
foot on the ground, its base has stayed lower than ``safety.fall_height`` (m) above its lowest
foot for ``FALL_HEIGHT_TIME`` s: the kinematic base height above the ground, ``max_i (-(R p_i)_z +
rho_i)`` over every foot ``i`` (a foot in the air lower than those in contact, reaching down a step
with the others on the step above, says the ground under the base is that low too; a collapsed
base's feet are on the ground or above it), ``p_i`` the foot site's position in the base frame
(Pinocchio, joint estimate), ``rho_i`` its contact radius, a sphere's or a wheel's (a wheel's site is
its hub: :func:`~sim2real.deploy.estimation.base_params.foot_radii`), and ``R`` the estimated
orientation. The tilt trips at once; the height must persist, because a low trot
on one foot in contact dips under the limit for a tick while a collapsed base stays down. A third
signal, ``sinking``, needs neither the feet nor the tilt: the estimated base sinking faster than
``FALL_SPEED`` for ``FALL_SPEED_TIME`` s while tilted past ``SINK_TILT_SHARE`` of the tilt limit,
or with its kinematic height under ``SINK_HEIGHT_SHARE`` of ``[base] standing_height``; upright,
on its feet or with none in contact (a hop a push threw it into), for ``UPRIGHT_SINK_TIME`` s
(the kinematic height falls with the feet, a base can drop upright on a slack support). An
upright robot catching a push crouches: its base sinks for a moment, a few centimetres (a holosoma
G1's 0.1-s sink stopped it 0.4 deg from upright, its base 0.67 m of its 0.757 m). No ground truth
is read: the same check runs on hardware.

The runtime's response (:mod:`sim2real.deploy.runtime`, cause ``fall``): a safe stop whose command is
joint damping (position mode: the target follows the measured pose, so the PD servo applies
``-kd dq`` only; what Unitree's deploy code does after a fall), latched in FAULTED until an
operator's reset. Every other safe stop of a legged robot damps the same way: holding a stance
against gravity is what overheats its motors.
"""

from __future__ import annotations

import functools
import math
import operator
from collections.abc import Callable

import numba
import numpy as np
import pinocchio as pin

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.core.stateful import check, put, take
from sim2real.deploy.estimation.base_kernel import _quat_to_mat, fma
from sim2real.deploy.estimation.base_params import foot_radii, require_floating_base
from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.kernels.tables import Table
from sim2real.robots import Robot

#: ``feet(e, out) -> bool``: env ``e``'s feet's positions in the base frame into ``out`` (n_feet,
#: 3) m, or False where it has none (:meth:`FallDetector.check`).
FootPositions = Callable[[int, np.ndarray], bool]
#: Default tilt limit, rad (our choice): a walking quadruped's base stays within ~0.3 rad of
#: upright; past 1 rad (57 deg) it cannot catch itself.
FALL_TILT = 1.0
#: Default height limit, m (our choice): about half a Go2's calf (0.21 m), the base near the floor.
FALL_HEIGHT = 0.12
#: How long the base must stay under the height limit, s (our choice): ten ticks at 50 Hz. A
#: collapsed base stays down for far longer; a one-tick dip of a walking robot's estimate does not.
FALL_HEIGHT_TIME = 0.2
#: Sinking speed, m/s, and for how long, s (our choice): a walking base's vertical velocity
#: stays within about 0.3 m/s; a base in free fall passes 1 m/s after 0.1 s and is then 5 cm
#: lower. Five ticks at 50 Hz.
FALL_SPEED = 1.0
FALL_SPEED_TIME = 0.1
#: The sinking of a base that is upright (on its feet, or in a hop with none in contact) must
#: last this long, s (our choice): 0.3 m
#: at FALL_SPEED, more than a walking robot's crouch catching a push (the G1's true 9 cm; the
#: H1's upright sink in a soak with pushes, 0.91 of its standing height) and under a free fall's
#: 0.45 s to the floor from a humanoid's 1 m.
UPRIGHT_SINK_TIME = 0.3
#: Share of the tilt limit past which a sinking base is falling over (our choice, from the H1's
#: 0.1-h soak with 1 m/s pushes: its one sinking stop of an upright robot at an
#: estimated 12.4 deg; its six of robots falling over at 28.7-54.1 deg): 0.4 (23 deg of 57).
SINK_TILT_SHARE = 0.4
#: Share of ``[base] standing_height`` under which a sinking base's kinematic height says it is
#: collapsing (our choice): half, below a Go2's trot (0.57 of it) and a humanoid's crouch.
SINK_HEIGHT_SHARE = 0.5
#: The three signals of a fall, the columns of :attr:`FallDetector.signals`.
SIGNALS = ("tilt", "height", "sinking")


class FallDetector:
    """The fall check of ``robot`` (module docstring).

    Args:
        robot: A floating-base robot; ``robot.config.safety.fall_tilt`` (rad) and
            ``fall_height`` (m) are its limits (default ``FALL_TILT``, ``FALL_HEIGHT``).
        envs: Batch size.

    Attributes:
        tilt_limit: rad. height_limit: m (0 disables the height check).
        height_ticks: control ticks the height must stay under ``height_limit``
            (``FALL_HEIGHT_TIME`` over the robot's control period, rounded up).
        radii: (n_feet,) m, each foot's contact radius
            (:func:`~sim2real.deploy.estimation.base_params.foot_radii`).
        height: (envs,) m, the last kinematic base height above the ground, above the lowest
            foot (NaN with no foot in contact).
        low_ticks: (envs,) int64, consecutive checks so far with ``height`` under the limit.
        speed_ticks: control ticks the base must sink faster than ``FALL_SPEED`` tilted or
            low (``FALL_SPEED_TIME``); upright_ticks: upright, on its feet or with none in
            contact (``UPRIGHT_SINK_TIME``), both rounded up.
        sink_tilt: rad, ``SINK_TILT_SHARE`` of ``tilt_limit``. sink_height: m,
            ``SINK_HEIGHT_SHARE`` of the standing height.
        sinking_ticks: (envs,) int64, consecutive checks so far with the base sinking so.
        signals: (envs, 3) bool, which signal of the last :meth:`check` fired, columns in
            :data:`SIGNALS` order (for the logs: a fall record says why it was called).

    Raises:
        ValueError: a fixed-base robot.
    """

    def __init__(self, robot: Robot, envs: int):
        require_floating_base(robot, "fall detection")
        s = robot.config.safety
        self.tilt_limit = float(FALL_TILT if s.fall_tilt is None else s.fall_tilt)
        self.height_limit = float(FALL_HEIGHT if s.fall_height is None else s.fall_height)
        self.model = robot.fixed_base_model
        self.data = self.model.createData()
        # the foot sites' frames in the fixed-base model (same names as in pin_model)
        frames = [robot.pin_model.frames[f] for f in robot.foot_frame_ids]
        self.feet = [self.model.getFrameId(f.name, f.type) for f in frames]
        self.radii = foot_radii(robot)
        self.height = np.full(envs, np.nan)
        self.height_ticks = max(1, int(np.ceil(FALL_HEIGHT_TIME / robot.control_period - 1e-9)))
        self.speed_ticks = max(1, int(np.ceil(FALL_SPEED_TIME / robot.control_period - 1e-9)))
        self.upright_ticks = max(
            self.speed_ticks, int(np.ceil(UPRIGHT_SINK_TIME / robot.control_period - 1e-9))
        )
        self.sink_tilt = SINK_TILT_SHARE * self.tilt_limit
        self.sink_height = SINK_HEIGHT_SHARE * float(robot.config.base.standing_height)
        self._ticks = np.zeros((2, envs), dtype=np.int64)
        self.low_ticks, self.sinking_ticks = self._ticks  # views: written in place
        self.signals = np.zeros((envs, len(SIGNALS)), dtype=bool)
        # the compiled check's constants and work arrays
        self._limits = np.array(
            [
                self.tilt_limit, self.height_limit, self.height_ticks, self.speed_ticks,
                self.upright_ticks, self.sink_tilt, self.sink_height, *self.radii,
            ],
            dtype=float,
        )  # fmt: skip
        self._foot_position = np.zeros((envs, len(self.feet), 3))
        self._fallen = np.zeros(envs, dtype=bool)
        self._bound = None  # (the state's arrays, _check bound to them): see screen
        # the compiled check compiled (or loaded from numba's cache) now, not in the first tick,
        # on a state of the runtime's layout; its counts then cleared
        self.check(RobotState.legged(envs, robot.n_joints, len(self.feet)))
        self.height[:] = np.nan
        self._ticks[:] = 0
        self.signals[:] = False

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """``height`` (envs,) m, ``low_ticks`` and ``sinking_ticks`` (envs,) int64 (copies;
        conventions of :mod:`sim2real.deploy.core.stateful`; the env axis has length 1 for one env
        ``env``)."""
        return take(self._fields(), env)

    def _fields(self) -> dict[str, np.ndarray]:
        return {
            "height": self.height,
            "low_ticks": self.low_ticks,
            "sinking_ticks": self.sinking_ticks,
        }

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        check(self._fields(), state, env)
        put(self._fields(), state, env)

    def __getstate__(self) -> dict:
        """A copy (``copy.deepcopy``, pickle) binds the check afresh: its binding names the
        state's arrays, which a copy of the detector alone does not share."""
        return self.__dict__ | {"_bound": None}

    @property
    def fallen_mask(self) -> np.ndarray:
        """(envs,) bool: the last check's falls, the array it writes (the compiled fall screen
        reads it: :func:`fall_screen`)."""
        return self._fallen

    def check(self, state: RobotState, feet: FootPositions | None = None) -> np.ndarray:
        """(envs,) bool: the envs whose estimated base is tilted, low or sinking past the
        limits.

        Args:
            state: A floating-base robot's estimate (``RobotState.legged``: ``base``,
                ``foot_contact``, ``q``).
            feet: Optional ``feet(e, out) -> bool`` (the base estimator's
                :meth:`~sim2real.deploy.estimation.base.BaseStateEstimator.foot_position`):
                env ``e``'s feet's positions in the base frame from ``state.q`` into ``out``
                (n_feet, 3) m, the feet in ``robot.foot_frame_ids`` order, or False where it
                has none (the detector's own forward kinematics then).
        """
        return self.screen(state, feet).copy()

    def screen(self, state: RobotState, feet: FootPositions | None = None) -> np.ndarray:
        """:meth:`check` into the detector's own (envs,) bool array, returned (overwritten by
        the next check): Pinocchio's placements (``feet``'s where it has them), then
        :func:`_check` bound to ``state``'s arrays (made again for other arrays)."""
        model, data, position = self.model, self.data, self._foot_position
        if self.height_limit > 0.0:  # every foot's position in the base frame (Pinocchio)
            for e in range(len(self.height)):
                row = position[e]
                if feet is not None and feet(e, row):
                    continue
                pin.forwardKinematics(model, data, state.q[e])
                for i, f in enumerate(self.feet):
                    row[i] = pin.updateFramePlacement(model, data, f).translation
        base = state.base
        key = (base.projected_gravity, base.linear_velocity_world, base.orientation)
        key += (state.foot_contact,)
        bound = self._bound
        if bound is None or not all(map(operator.is_, key, bound[0])):
            values = dict(
                limits=self._limits, gravity=key[0], velocity=key[1], orientation=key[2],
                contact=key[3], position=position, height=self.height, ticks=self._ticks,
                signals=self.signals, out=self._fallen,
            )  # fmt: skip
            table = CHECK.pack_or_none(**values)
            if table is not None:
                self._bound = bound = (key, bind(_check_table, table))
            else:  # through numba's dispatch
                self._bound = bound = (key, functools.partial(_check, **values))
        bound[1]()
        return self._fallen


#: The arrays of :func:`_check` (its arguments' names), one table.
CHECK = Table(
    "sim2real.deploy.estimation.fall:CHECK",
    limits="f8[*]", gravity="f8[envs,3]", velocity="f8[envs,3]", orientation="f8[envs,4]",
    contact="f8[envs,feet]", position="f8[envs,feet,3]", height="f8[envs]",
    ticks="i8[2,envs]", signals="b1[envs,*]", out="b1[envs]",
)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _check_table(t):
    """:func:`_check` on the packed table ``t`` (:data:`CHECK`): one array to unbox."""
    _check(
        t.limits, t.gravity, t.velocity, t.orientation, t.contact, t.position, t.height,
        t.ticks, t.signals, t.out,
    )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _check(limits, gravity, velocity, orientation, contact, position, height, ticks, signals, out):
    """:meth:`FallDetector.check` after Pinocchio's placements ``position`` (envs, n_feet, 3) m,
    every env: ``limits`` (tilt rad, height m, height ticks, speed ticks, upright speed ticks,
    sinking tilt rad, sinking height m, then each foot's contact radius m); ``ticks`` (2, envs)
    the low and the sinking runs; ``height``, ``signals``, ``out`` written."""
    rot = np.empty((3, 3))
    for e in range(gravity.shape[0]):
        g0, g1, g2 = gravity[e, 0], gravity[e, 1], gravity[e, 2]  # tilt_of, one row
        up = -(g2 / math.sqrt(g0 * g0 + g1 * g1 + g2 * g2))
        up = 1.0 if up > 1.0 else (-1.0 if up < -1.0 else up)
        tilt = math.acos(up)
        signals[e, 0] = tilt > limits[0]  # NaN compares False
        ticks[1, e] = ticks[1, e] + 1 if velocity[e, 2] < -FALL_SPEED else 0
        signals[e, 1] = False
        if limits[1] > 0.0:
            height[e] = np.nan
            _quat_to_mat(orientation[e], rot)
            touching, lowest = False, -np.inf
            for i in range(contact.shape[1]):  # max() of every foot, in their order
                touching = touching or contact[e, i] > 0.5
                p = position[e, i]
                below = -fma(rot[2, 2], p[2], fma(rot[2, 0], p[0], rot[2, 1] * p[1]))
                below += limits[7 + i]  # the foot's contact radius: down to the ground
                if below > lowest:
                    lowest = below
            if touching:  # a foot on the ground; none: a hop, no height
                height[e] = lowest
            ticks[0, e] = ticks[0, e] + 1 if height[e] < limits[1] else 0
            signals[e, 1] = ticks[0, e] >= limits[2]
        # sinking: tilted or low; upright and no foot in contact (NaN) is a hop, not low
        upright = tilt <= limits[5] and not height[e] < limits[6]  # NaN compares False
        signals[e, 2] = ticks[1, e] >= (limits[4] if upright else limits[3])
        out[e] = signals[e, 0] or signals[e, 1] or signals[e, 2]


@numba.njit(cache=True, nogil=True)
def stale_screen(contact, foot_contact, clock, since_fresh, stale_limit, stale, time) -> bool:
    """The runtime's legged tick after the base estimate
    (:meth:`sim2real.deploy.kinds.legged_tick.LeggedTick.update`): the estimator's ``contact``
    (envs, n_feet) bool into the state's ``foot_contact`` (1.0 / 0.0), ``clock`` (envs,) the
    runtime's ``time`` s; ``stale`` (envs,) bool: an IMU silent for more
    than ``stale_limit`` s (``since_fresh``, the estimator's). Returns whether any is stale."""
    any_stale = False
    for e in range(contact.shape[0]):
        for i in range(contact.shape[1]):
            foot_contact[e, i] = 1.0 if contact[e, i] else 0.0
        clock[e] = time
        s = since_fresh[e] > stale_limit  # NaN compares False
        stale[e] = s
        any_stale = any_stale or s
    return any_stale


@numba.njit(cache=True, nogil=True)
def fall_screen(fallen, mode, lying, signals, out, running, ramp_in) -> bool:
    """``out`` (envs,) bool: the envs ``fallen`` (:meth:`FallDetector.screen`) RUNNING or in
    RAMP_IN (the modes ``running``, ``ramp_in``), where no lie-down was asked (``lying``) or
    the base tilted (``signals[:, 0]``). Returns whether any."""
    any_fall = False
    for e in range(fallen.shape[0]):
        m = mode[e]
        f = fallen[e] and (m == running or m == ramp_in) and (not lying[e] or signals[e, 0])
        out[e] = f
        any_fall = any_fall or f
    return any_fall
