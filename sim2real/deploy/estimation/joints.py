"""Joint state estimation: a position + velocity Kalman filter per joint, batched over ``envs``.

Model (per joint, state ``x = [q, dq]``, rad and rad/s): the acceleration the drive was commanded
(control input ``u``, rad/s^2), plus white-noise acceleration that is piecewise constant over each
prediction interval ("discrete white noise acceleration", Bar-Shalom, Li, Kirubarajan, *Estimation
with Applications to Tracking and Navigation*, Wiley 2001, sec. 6.3.2;
``filterpy.common.Q_discrete_white_noise(2, dt, var)``)::

    x' = F(dt) x + B(dt) u
    F(dt) = [[1, dt], [0, 1]]          Q(dt) = var * [[dt^4 / 4, dt^3 / 2], [dt^3 / 2, dt^2]]
    B(dt) = [[dt^2 / 2], [dt]]         H = [[1, 0]],  R = measurement_sigma^2

Without an input (``u = 0``) this is the constant-velocity model, which lags an accelerating joint
by about ``a / omega^2`` (``omega ~ (var / R)^(1/4)``). An arm's filter gets the smoother's
commanded acceleration (``CommandSmoother.mean_acceleration``) in position and velocity mode; a
floating base's none (``SafetyGuard.estimator_input``): its PD targets jump, their acceleration
is not the joints'. Latency is extrapolated with the input only with ``input_extrapolates``.
Drives that report each joint's velocity with its angle (Unitree's ``motor_state.dq``; robot.toml's
``[sensors] velocity_noise_sigma``) give a second measurement, ``H = [0, 1]``
(:func:`~sim2real.deploy.estimation.kernel.absorb_velocity`): without it a stepping leg's speed
estimate lagged by two to three control periods.

Time stamps: a joint's filter lives at ``filter_time``, the sample time of the last reading it
absorbed; a later reading is absorbed, an older, repeated or future one counted in
``stale_readings``, a missing (non-finite) one in ``missing_readings``. The *output* is the
prediction from ``filter_time`` to ``frame.time``, not stored: latency is bridged by
extrapolation, a dropout is a predict-only step.

The tick is one numba kernel (:mod:`sim2real.deploy.estimation.kernel`); its reference runs one
``filterpy.kalman.KalmanFilter(dim_x=2, dim_z=1)`` per (env, joint) (:mod:`~.reference`).
"""

from __future__ import annotations

import functools

import numpy as np

from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.core.stateful import put, take
from sim2real.deploy.estimation.joint_tuning import (
    MAX_TRACKING_INDEX,
    MIN_VELOCITY_SIGMA,
    PROCESS_NOISE_FRACTION,
    VELOCITY_SIGMA_BOUND,
    motion_acceleration,
)
from sim2real.deploy.estimation.kernel import KalmanArgs, absorb_velocity, kalman_tick
from sim2real.deploy.kernels.calls import bind, fits
from sim2real.robots import Robot


def _absorb_copy(velocity: np.ndarray, rest: tuple) -> None:
    """:func:`~sim2real.deploy.estimation.kernel.absorb_velocity` on a float64 C-contiguous copy
    of ``velocity`` (a frame whose array the bound call does not take)."""
    absorb_velocity(np.ascontiguousarray(velocity, dtype=np.float64), *rest)


class JointStateEstimator:
    """Kalman filter of joint position and velocity for ``envs`` robots of ``n`` joints.

    Args:
        robot: The robot description (limits, sensor settings).
        envs: Batch size.
        process_noise: Variance ``var`` of the white-noise acceleration, (rad/s^2)^2, as
            ``Q_discrete_white_noise(2, dt, var)`` takes it; scalar or (n,). Default
            ``(PROCESS_NOISE_FRACTION * motion_acceleration(robot))^2``
            (:mod:`sim2real.deploy.estimation.joint_tuning`) (Bar-Shalom et al. 2001,
            sec. 6.3.2: standard deviation 0.5 to 1 times the largest acceleration).
        measurement_sigma: Encoder noise standard deviation, rad; scalar or (n,). Default
            ``robot.config.sensors.encoder_noise_sigma``, floored at the quantization noise
            ``(2 pi / encoder_resolution) / sqrt(12)`` (uniform rounding error) so that ``R > 0``,
            and at ``sqrt(process_noise) dt^2 / MAX_TRACKING_INDEX`` (a velocity estimate that
            does not oscillate; ``dt`` the control period). Where that last floor acts, the
            reading's angle is absorbed a second time into the angle alone at
            ``angle_rest_variance``, so the angle still follows the encoder at its own noise.
        input_extrapolates: Whether the output's extrapolation from the newest reading to the
            frame's time uses the control input (default) or constant velocity (module
            docstring; the runtime gives a floating-base robot's filter no input at all).

    Attributes:
        covariance: (envs, n, 2, 2) covariance of ``[q, dq]`` at ``filter_time`` (rad^2,
            rad^2/s, rad^2/s^2), symmetric. A writable view: a value written into it (fault
            injection) is checked by the next :meth:`update`.
        position, velocity: (envs, n) rad, rad/s, the filter state at ``filter_time`` (views).
        filter_time: (envs, n) s, sample time of the last absorbed reading (or of the reset).
        time_since_fresh: (envs, n) s, ``frame.time - filter_time`` at the last update: the age of
            the newest absorbed reading, latency included. The runtime safe-stops when it exceeds
            ``robot.stale_limit``.
        stale_readings, missing_readings, reinitializations: (envs,) int counters since the last
            :meth:`reset` (sums over the joints of ``*_per_joint``, (envs, n)).
        angle_rest_variance: (n,) rad^2, ``1 / (1 / encoder^2 - 1 / R)``: the share of the
            encoder's accuracy the tracking-index floor held back from the joint update, absorbed
            after it into the angle alone (gain ``[k0, 0]``, Joseph's form; the velocity stays
            the floored update's: the angle's residual of a leg whose acceleration steps within
            a period is no measure of its speed). inf where no floor acts or
            ``measurement_sigma`` is given. Without it a stepping leg's angle lagged its encoder
            (docs/legged.md).
        initial_covariance: (n, 2, 2), ``diag(R, velocity_limit^2)``: the pose is known to the
            encoder's accuracy, the velocity only to within the joint's velocity limit.
        covariance_bound: (n, 2), largest accepted variances of position and velocity:
            ``(upper - lower)^2`` (a standard deviation wider than the joint's whole travel) and
            ``(VELOCITY_SIGMA_BOUND * velocity_limit)^2``.

    Raises:
        ValueError: ``envs < 1``, or noise values that are not finite and positive.
    """

    def __init__(
        self,
        robot: Robot,
        envs: int,
        process_noise: float | np.ndarray | None = None,
        measurement_sigma: float | np.ndarray | None = None,
        input_extrapolates: bool = True,
    ):
        if envs < 1:
            raise ValueError(f"envs must be >= 1, got {envs}")
        n = robot.n_joints
        self.robot, self.envs, self.n_joints = robot, envs, n
        self.input_extrapolates = bool(input_extrapolates)
        sensors = robot.config.sensors
        if process_noise is None:
            process_noise = (PROCESS_NOISE_FRACTION * motion_acceleration(robot)) ** 2
        self.process_noise = self._per_joint("process_noise", process_noise)
        encoder = None
        if measurement_sigma is None:
            floor = 2.0 * np.pi / sensors.encoder_resolution / np.sqrt(12.0)
            stable = np.sqrt(self.process_noise) * robot.control_period**2 / MAX_TRACKING_INDEX
            encoder = max(sensors.encoder_noise_sigma, floor)
            measurement_sigma = np.maximum(encoder, stable)
        self.measurement_variance = self._per_joint("measurement_sigma", measurement_sigma) ** 2
        self.angle_rest_variance = np.full(n, np.inf)
        if encoder is not None:
            held = self.measurement_variance > encoder**2 * (1.0 + 1e-9)
            kept = np.where(held, self.measurement_variance, 1.0)
            self.angle_rest_variance = np.where(held, 1.0 / (1.0 / encoder**2 - 1.0 / kept), np.inf)
        #: (n,) (rad/s)^2, the drives' reported velocity as a measurement (``[sensors]
        #: velocity_noise_sigma``, at least ``MIN_VELOCITY_SIGMA``); None: not fused
        self.velocity_variance = None
        if sensors.velocity_noise_sigma is not None:
            sigma = max(sensors.velocity_noise_sigma, MIN_VELOCITY_SIGMA)
            self.velocity_variance = np.full(n, sigma**2)
        self.initial_covariance = np.zeros((n, 2, 2))
        self.initial_covariance[:, 0, 0] = self.measurement_variance
        self.initial_covariance[:, 1, 1] = robot.velocity_limit**2
        self.covariance_bound = np.stack(
            [
                (robot.position_upper - robot.position_lower) ** 2,
                (VELOCITY_SIGMA_BOUND * robot.velocity_limit) ** 2,
            ],
            axis=-1,
        )

        shape = (envs, n)
        # Filter state, one (8, envs, n) array (the kernel's one argument): x[0] = position,
        # x[1] = velocity; p[k] = P[k // 2, k % 2] (contiguous rows for the closed-form algebra;
        # ``covariance`` is a (envs, n, 2, 2) view of them); filter_time; time_since_fresh.
        self._filt = np.zeros((8, envs, n))
        self._x, self._p = self._filt[0:2], self._filt[2:6]
        self.filter_time, self.time_since_fresh = self._filt[6], self._filt[7]
        self._x[0] = np.nan
        self.filter_time.fill(np.nan)
        self.time_since_fresh.fill(np.inf)
        # rows missing, stale, re-initializations (the public counters are views)
        self._counts = np.zeros((3, *shape), dtype=np.int64)
        self.missing_per_joint, self.stale_per_joint = self._counts[0], self._counts[1]
        self.reinitializations_per_joint = self._counts[2]
        self.covariance[:] = self.initial_covariance
        self._initialized = np.zeros(envs, dtype=bool)
        self._all_initialized = False

        # work arrays, (envs, n): the tick allocates nothing
        self._u = np.zeros(shape)  # the control input when the caller's cannot be read as is
        # row views, made once (unpacking a (2, envs, n) array every tick would create them anew)
        self._xv = tuple(self._x)
        self._flags = np.zeros((2, *shape), dtype=bool)  # rows fresh, good
        self._fresh, self._good = self._flags[0], self._flags[1]

        # the compiled kernel's per-joint constants: rows var, r, the covariance bounds and the
        # angle's rest variance
        self._consts = np.ascontiguousarray(
            np.stack(
                [
                    self.process_noise,
                    self.measurement_variance,
                    *self.covariance_bound.T,
                    self.angle_rest_variance,
                ]
            )
        )
        #: the kernel's arguments for the last frame's, state's and input's arrays
        #: (:meth:`_bind`), and those arrays, compared by identity at each update
        self._args: KalmanArgs | tuple = ()
        self._bound: tuple = ()
        self._velocity_call = None  # absorb_velocity bound to the frame's velocity (_bind)
        self._warm_up()

    def _warm_up(self) -> None:
        """Compile :func:`~sim2real.deploy.estimation.kernel.kalman_tick` (or load numba's cache) now, not
        in a tick, on copies: the call writes its outputs (time_since_fresh among them)."""
        envs, n = self.envs, self.n_joints
        args = self._kernel_args(SensorFrame.empty(envs, n), RobotState.zeros(envs, n), self._u)
        kalman_tick(2, *(np.copy(a) if isinstance(a, np.ndarray) else a for a in args))
        if self.velocity_variance is not None:
            a = [np.copy(x) for x in (args.filt, args.flags, args.now, args.u, args.q_out)]
            absorb_velocity(np.zeros((envs, n)), self.velocity_variance, *a, a[-1], True)

    def _per_joint(self, name: str, value) -> np.ndarray:
        arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (self.n_joints,)).copy()
        if not (np.isfinite(arr).all() and (arr > 0).all()):
            raise ValueError(f"{name} must be finite and > 0 for every joint, got {arr}")
        return arr

    # ------------------------------------------------------------------ views and counters
    @property
    def initialized(self) -> bool:
        """Whether :meth:`reset` was called for every env (else :meth:`update` raises)."""
        return self._all_initialized

    @property
    def filter_state(self) -> np.ndarray:
        """(8, envs, n) float64, the kernel's ``filt`` (the live array; rows in
        :func:`~sim2real.deploy.estimation.kernel.kalman_tick`'s docstring): ``position``,
        ``velocity``, ``covariance``, ``filter_time`` and ``time_since_fresh`` are its views."""
        return self._filt

    @property
    def position(self) -> np.ndarray:
        """(envs, n) rad, filter position at ``filter_time`` (a view)."""
        return self._x[0]

    @property
    def velocity(self) -> np.ndarray:
        """(envs, n) rad/s, filter velocity at ``filter_time`` (a view)."""
        return self._x[1]

    @property
    def covariance(self) -> np.ndarray:
        """(envs, n, 2, 2) covariance of ``[q, dq]`` at ``filter_time`` (a writable view)."""
        return self._p.reshape(2, 2, self.envs, self.n_joints).transpose(2, 3, 0, 1)

    @property
    def stale_readings(self) -> np.ndarray:
        """(envs,) readings discarded as stale, repeated, reordered or future-stamped."""
        return self.stale_per_joint.sum(axis=1)

    @property
    def missing_readings(self) -> np.ndarray:
        """(envs,) readings that did not arrive or were not finite (predict only)."""
        return self.missing_per_joint.sum(axis=1)

    @property
    def reinitializations(self) -> np.ndarray:
        """(envs,) joints re-initialized after their filter degenerated."""
        return self.reinitializations_per_joint.sum(axis=1)

    # ------------------------------------------------------------------ lifecycle
    def reset(self, q: np.ndarray, t, envs: np.ndarray | None = None) -> None:
        """Initialize the filters at a measured pose, at rest.

        Sets ``position = q``, ``velocity = 0``, ``covariance = initial_covariance``,
        ``filter_time = t``, ``time_since_fresh = 0`` and zeroes the counters of the reset envs.
        A reading stamped ``t`` that arrives later is a repeat of ``q`` and counts as stale.

        Args:
            q: (envs, n) or (n,) rad, measured joint angles (finite).
            t: s, sample time of ``q``: a float, (envs,) or (envs, n) (finite).
            envs: Optional boolean mask (envs,) or indices of the envs to reset; default all.

        Raises:
            ValueError: ``q`` or ``t`` of the wrong shape, or not finite in a reset env.
        """
        shape = (self.envs, self.n_joints)
        sel = np.arange(self.envs) if envs is None else np.arange(self.envs)[envs]
        q = np.asarray(q, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64)
        try:
            q = np.broadcast_to(q, shape)
            t = np.broadcast_to(t[:, None] if t.ndim == 1 else t, shape)
        except ValueError as exc:
            raise ValueError(
                f"reset: q must be (n,) or {shape}, t a float, ({self.envs},) or {shape}; "
                f"got q {q.shape}, t {t.shape}"
            ) from exc
        if not (np.isfinite(q[sel]).all() and np.isfinite(t[sel]).all()):
            raise ValueError("reset: q and t must be finite (a pose that was actually measured)")
        self._x[0, sel] = q[sel]
        self._x[1, sel] = 0.0
        self.covariance[sel] = self.initial_covariance
        self.filter_time[sel] = t[sel]
        self.time_since_fresh[sel] = 0.0
        for counter in (
            self.stale_per_joint,
            self.missing_per_joint,
            self.reinitializations_per_joint,
        ):
            counter[sel] = 0
        self._initialized[sel] = True
        self._all_initialized = bool(self._initialized.all())

    # ------------------------------------------------------------------ state
    def _state_fields(self) -> dict[str, np.ndarray]:
        return {
            "position": self._x[0],
            "velocity": self._x[1],
            "covariance": self.covariance,
            "filter_time": self.filter_time,
            "time_since_fresh": self.time_since_fresh,
            "stale_per_joint": self.stale_per_joint,
            "missing_per_joint": self.missing_per_joint,
            "reinitializations_per_joint": self.reinitializations_per_joint,
            "initialized": self._initialized,
        }

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """The filters' state (copies; conventions of :mod:`sim2real.deploy.core.stateful`): ``position``,
        ``velocity`` (envs, n) rad, rad/s and ``covariance`` (envs, n, 2, 2) at
        ``filter_time`` (envs, n) s, ``time_since_fresh`` (envs, n) s, the per-joint counters
        (envs, n) int64 and ``initialized`` (envs,) bool (:meth:`reset` was called); the env
        axis has length 1 for one env ``env``."""
        return take(self._state_fields(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        put(self._state_fields(), state, env)
        self._all_initialized = bool(self._initialized.all())

    # ------------------------------------------------------------------ the tick
    def update(
        self, frame: SensorFrame, state: RobotState, acceleration: np.ndarray | None = None
    ) -> RobotState:
        """Absorb the fresh readings of ``frame`` and write the estimates at ``frame.time``.

        ``acceleration`` is the control input ``u``, (envs, n) rad/s^2: the acceleration the
        drives were commanded since the previous frame (None: 0, the constant-velocity model).
        It drives every prediction of this call, readings' and output's.

        Fills ``state.q`` (rad) and ``state.dq`` (rad/s), both (envs, n), predicted from
        ``filter_time`` to ``frame.time``, and copies ``frame.winding_temperature`` (degC) into
        ``state.winding_temperature`` where it is finite. Updates the counters,
        ``time_since_fresh`` and ``covariance`` (see the module docstring for the rules).

        After the step the covariance is symmetrized and every joint checked: a joint whose state
        is not finite, or whose covariance is not positive definite or exceeds
        ``covariance_bound``, is re-initialized and counted in ``reinitializations``: from this
        frame's reading if it had a fresh one (``filter_time`` = its stamp), otherwise from its
        last estimate (``filter_time`` unchanged); velocity clipped to the velocity limit (0 if not
        finite), ``covariance = initial_covariance``. A joint whose position itself is lost and
        has no reading keeps a NaN estimate and ``time_since_fresh = inf`` (the runtime
        safe-stops) until a reading arrives; it is counted once.

        Returns:
            ``state``, updated in place.

        Raises:
            RuntimeError: :meth:`reset` was not called for every env.
            ValueError: a frame of the wrong shape.
        """
        if not self._all_initialized:
            raise RuntimeError("JointStateEstimator.update before reset(q, t) of every env")
        b = self._bound
        if not (
            b
            and frame.position is b[0]
            and frame.position_stamp is b[1]
            and frame.time is b[2]
            and frame.winding_temperature is b[3]
            and state is b[4]
            and state.q is b[5]
            and acceleration is b[6]
            and frame.velocity is b[7]
        ):
            self._bind(frame, state, acceleration)
        elif self._copy_input:
            np.copyto(self._u, acceleration)
        status = kalman_tick(0, *self._args)
        if status:
            self._recover(status, frame)
        if self._velocity_call is not None:
            self._velocity_call()
        return state

    def kernel_arrays(self, frame: SensorFrame, state: RobotState, acceleration) -> KalmanArgs:
        """The kernel's arguments over these arrays, the live ones for a caller's table of
        addresses (bound as by :meth:`update`: ``acceleration`` (envs, n) rad/s^2 or None is read
        in place if float64 C-contiguous, else ``u`` is the estimator's own array, which needs
        ``acceleration`` copied in before each call unless it is None).

        Raises:
            ValueError: ``frame.position`` or ``position_stamp`` not shaped (envs, n).
        """
        self._bind(frame, state, acceleration)
        return self._args

    def recover(self, status: int, frame: SensorFrame, state: RobotState, acceleration) -> None:
        """The rare path of a caller's compiled call of the kernel (arrays of
        :meth:`kernel_arrays`) that returned ``status`` (the phase whose check failed, 1 or 2):
        re-initialize the degenerate joints as :meth:`update` does and run the kernel on to the
        outputs. Raises ValueError: a frame of the wrong shape."""
        self._bind(frame, state, acceleration)
        self._recover(status, frame)

    def _check_frame(self, frame: SensorFrame) -> None:
        """Raises ValueError: ``frame.position`` or ``position_stamp`` not shaped (envs, n)."""
        z, ts = frame.position, frame.position_stamp
        x0 = self._xv[0]
        if z.shape != x0.shape or ts.shape != x0.shape:
            raise ValueError(
                f"frame: expected position and position_stamp shaped {x0.shape}, "
                f"got {z.shape} and {ts.shape}"
            )

    def _bind(self, frame: SensorFrame, state: RobotState, acceleration) -> None:
        """Check a frame, state or input whose arrays differ from the last update's and make
        the kernel's arguments for them. The input is read in place when it is a float64
        C-contiguous (envs, n) array (the smoother's), else copied into ``_u`` at each update
        (zeros for None)."""
        self._check_frame(frame)
        u, f = acceleration, frame
        in_place = isinstance(u, np.ndarray) and u.dtype == np.float64
        in_place = in_place and u.shape == self._u.shape and u.flags.c_contiguous
        self._copy_input = not in_place and u is not None
        if u is None:
            self._u.fill(0.0)
        elif self._copy_input:
            np.copyto(self._u, u)
        self._args = a = self._kernel_args(frame, state, u if in_place else self._u)
        self._bound = (f.position, f.position_stamp, f.time, f.winding_temperature, state,
                       state.q, acceleration, f.velocity)  # fmt: skip
        self._velocity_call = None
        if self.velocity_variance is not None and f.velocity is not None:
            if f.velocity.shape != f.position.shape:
                raise ValueError(
                    f"frame: expected velocity shaped {f.position.shape}, got {f.velocity.shape}"
                )
            rest = (self.velocity_variance, a.filt, a.flags, a.now, a.u, a.q_out, a.dq_out,
                    a.input_extrapolates)  # fmt: skip
            v = f.velocity
            if fits(v, np.float64, v.shape) and all(fits(x, x.dtype, x.shape) for x in rest[:-1]):
                self._velocity_call = bind(absorb_velocity, v, *rest)
            else:  # an array the bound call does not take: numba's dispatch, on a copy
                self._velocity_call = functools.partial(_absorb_copy, v, rest)

    def _recover(self, status: int, frame: SensorFrame) -> None:
        """A degenerate joint (the kernel's ``status``, its phase): re-initialize it, go on from
        the next phase, until the outputs are written (the rare path)."""
        z, ts = frame.position, frame.position_stamp
        while status:
            with np.errstate(invalid="ignore", over="ignore"):
                self._reinitialize(z, ts)
            status = kalman_tick(status, *self._args)

    # ------------------------------------------------------------------ internals
    def _kernel_args(self, frame: SensorFrame, state: RobotState, u: np.ndarray) -> KalmanArgs:
        """Arguments of :func:`sim2real.deploy.estimation.kernel.kalman_tick` after ``phase``."""
        return KalmanArgs(
            frame.position,
            frame.position_stamp,
            frame.time,
            frame.winding_temperature,
            u,
            self._filt,
            self._consts,
            self._counts,
            self._flags,
            state.q,
            state.dq,
            state.winding_temperature,
            self.input_extrapolates,
        )

    def _reinitialize(self, z: np.ndarray, ts: np.ndarray) -> None:
        """Re-initialize the joints that are not good (the rare path: it may allocate)."""
        bad = ~self._good
        fresh = self._fresh
        x0, x1 = self._x[0], self._x[1]
        already_lost = np.isneginf(self.filter_time) & ~fresh
        self.reinitializations_per_joint += bad & ~already_lost
        measured = bad & fresh
        x0[measured] = z[measured]
        self.filter_time[measured] = ts[measured]
        fresh[measured] = False  # absorbed by the re-initialization
        lost = bad & ~measured & ~np.isfinite(x0)
        x0[lost] = np.nan
        self.filter_time[lost] = -np.inf
        vlim = np.broadcast_to(self.robot.velocity_limit, x1.shape)
        velocity = np.clip(np.where(np.isfinite(x1), x1, 0.0), -vlim, vlim)
        x1[bad] = velocity[bad]
        self.covariance[bad] = np.broadcast_to(self.initial_covariance, self.covariance.shape)[bad]
