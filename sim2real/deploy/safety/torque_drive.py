"""The guard's model of torque mode: the motion a torque command commits the robot to, and the
brake that ends it.

A torque command has no trajectory: the plant integrates it. What it commits the robot to is one
control period under that torque (the joints' acceleration from Pinocchio's forward dynamics at
the estimated state, :meth:`TorqueDrive.motion`) and then the brake the guard can always apply:
a computed-torque stop (:meth:`TorqueDrive.brake`), ``tau = M(q) a + C(q, dq) dq + g(q)`` with
each joint decelerating at its acceleration limit (times the derated drive's headroom) until it
rests, which takes the coupling between the joints out of the stop. The motion envelope
(:mod:`sim2real.deploy.safety.envelope`) certifies that motion as it certifies a servo's command path
(the brake's deceleration taken at :data:`BRAKE_TRUST` of the commanded one, for the masses and
friction the model does not know), and the same box must stay inside the soft joint limits
(:meth:`TorqueDrive.beyond_limits`). A step whose motion cannot be certified is replaced by the
brake; the next tick's step starts from it (the smoother's rate limit follows).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from sim2real.deploy.safety.drive import ESTIMATE_SIGMAS
from sim2real.deploy.smoothing.smoother import TORQUE_RISE_TIME
from sim2real.robots import Robot
from sim2real.robots.chain_bounds import inertia_bound

#: Share of the commanded deceleration the guard counts on (our choice): the soak randomizes link
#: masses +-20 % and actuator strength +-10 %; the computed torque assumes the nominal masses.
BRAKE_TRUST = 0.7
#: rad/s, the stop's hold: once braked, each joint is pulled back to where its stop began by a
#: critically damped PD of this natural frequency (our choice: 2 Hz, slow against the drives'
#: current loops, fast against a sag), its acceleration within the stop's deceleration. Without it
#: a velocity-only stop drifts with the estimate's noise (a braked ur5 sank out of its box).
HOLD_FREQUENCY = 4.0 * np.pi
#: Share of the step's acceleration by which the true one may differ from the model's (our
#: choice, as :data:`BRAKE_TRUST`).
STEP_UNCERTAINTY = 0.3


class TorqueDrive:
    """Torque mode's motion and brake for ``envs`` robots (module docstring).

    Args:
        robot: The robot (acceleration, velocity and effort limits, soft joint limits, control
            period, the nominal dynamics of its MJCF through Pinocchio).
        envs: Batch size.

    Attributes:
        deceleration: (n,) rad/s^2, the brake's commanded deceleration at full effort: the
            acceleration limits (robot.toml, sized against the worst gravity load).
        brake_limits: (2, n) the deceleration the envelope counts on (:data:`BRAKE_TRUST` of
            ``deceleration``) and the jerk of the smoother's torque rate limit on the heaviest
            load, ``effort_limit / (TORQUE_RISE_TIME * inertia_bound)``: the envelope's brake.
        command: (envs, n) N m, the last committed torque (the brake's rate limit starts there).
    """

    def __init__(self, robot: Robot, envs: int):
        self.robot, self.envs = robot, envs
        n = robot.n_joints
        self.dt = robot.control_period
        self.deceleration = np.asarray(robot.acceleration_limit, dtype=float)
        jerk = robot.effort_limit / (TORQUE_RISE_TIME * inertia_bound(robot))
        self.brake_limits = np.stack([BRAKE_TRUST * self.deceleration, jerk])
        self._rate = robot.effort_limit * self.dt / TORQUE_RISE_TIME
        self.command = np.zeros((envs, n))
        #: (envs, n, 2, 2) the joint estimator's covariance of ``[q, dq]`` (rad^2, rad^2/s^2),
        #: a view the runtime sets (:class:`sim2real.deploy.estimation.joints.JointStateEstimator`), or
        #: None: the estimate's error then widens nothing
        self.covariance = None
        #: (envs, n) rad, where each env's current stop began (:meth:`brake`)
        self.hold = np.zeros((envs, n))
        #: (envs,) bool, the envs the last committed tick braked
        self.braked = np.zeros(envs, dtype=bool)
        self._braking = np.zeros(envs, dtype=bool)
        self.lower, self.upper = robot.soft_lower, robot.soft_upper
        self._model = robot.fixed_base_model
        self._data = self._model.createData()
        self.velocity_limit = np.asarray(robot.soft_velocity_limit, dtype=float)
        self._path = np.zeros((2, 3, envs, n))
        self._slack = np.zeros((envs, n))
        self._acc = np.zeros((envs, n))
        self._state = np.zeros((2, envs, n))
        #: (envs, n) rad/s^2, the acceleration the last committed torque gives at the estimate
        #: (:meth:`commit`): the joint estimator's control input in torque mode
        self.acceleration = np.zeros((envs, n))

    def motion(self, q, dq, command):
        """The step's motion for the envelope: ``(before, after, slack)``, (3, envs, n) the
        position, velocity and acceleration at the estimate (``q`` rad, ``dq`` rad/s) and one
        period of ``command`` (envs, n) N m later (with the torque's acceleration, which the
        brake ramps down at the rate limit), and
        (envs, n) rad the slack of the step's unknown share (:data:`STEP_UNCERTAINTY` of its
        displacement by acceleration) and of the estimate's (:data:`ESTIMATE_SIGMAS` standard
        deviations of its position, and of its speed over the stop, from :attr:`covariance`);
        views reused per call."""
        dt, acc = self.dt, self._acc
        self._state[0], self._state[1] = q, dq
        for e in range(self.envs):
            acc[e] = pin.aba(self._model, self._data, q[e], dq[e], command[e])
        before, after = self._path
        before[0], before[1], before[2] = q, dq, 0.0
        np.multiply(acc, dt, out=after[1])
        after[1] += dq
        np.multiply(dq, dt, out=after[0])
        after[0] += q
        after[0] += 0.5 * dt * dt * acc
        after[2] = acc
        np.multiply(np.abs(acc), STEP_UNCERTAINTY * dt * dt, out=self._slack)
        if self.covariance is not None:  # the estimate's error, and its speed's over the stop
            p = self.covariance
            stop = np.abs(after[1]) / self.brake_limits[0] + dt
            self._slack += ESTIMATE_SIGMAS * np.sqrt(np.maximum(p[..., 0, 0], 0.0))
            self._slack += ESTIMATE_SIGMAS * np.sqrt(np.maximum(p[..., 1, 1], 0.0)) * stop
        return before, after, self._slack

    def beyond_limits(self, box: np.ndarray, out: np.ndarray) -> np.ndarray:
        """(envs,) bool into ``out``: the envs whose motion box (``box`` (5, envs, n) of the
        envelope's kernel: centre, half-width, ...) leaves a soft joint limit (one already
        outside may only move back: its bound is the estimate), or whose speed
        after the step (of the last :meth:`motion`, with its unknown share, and what it gains
        while the brake ramps its acceleration down) exceeds the soft velocity limit."""
        lo, hi = box[0] - box[1], box[0] + box[1]
        # a joint already past a soft limit (pushed, or run out before) may move back, not on
        q, slack = self._state[0], self._slack
        lower = np.minimum(self.lower, q - slack)
        upper = np.maximum(self.upper, q + slack)
        v, a = self._path[1, 1], self._acc
        toward = np.maximum(a * np.sign(v), 0.0)  # gained while the brake ramps it down
        speed = np.abs(v) + STEP_UNCERTAINTY * self.dt * np.abs(a)
        speed += toward * toward / (2.0 * self.brake_limits[1])
        np.any((lo < lower) | (hi > upper) | (speed > self.velocity_limit), axis=1, out=out)
        return out

    def commit(self, command: np.ndarray) -> None:
        """The tick's final torque ``command`` (envs, n) N m: :attr:`acceleration` at the
        estimate of the last :meth:`motion` (its own for the envs that kept the step's torque,
        Pinocchio's forward dynamics again for those :meth:`brake` replaced), and
        :attr:`command`."""
        q, dq = self._state
        np.copyto(self.command, command)
        np.copyto(self.acceleration, self._acc)
        for e in np.flatnonzero(self._braking):
            self.acceleration[e] = pin.aba(self._model, self._data, q[e], dq[e], command[e])
        np.copyto(self.braked, self._braking)
        self._braking.fill(False)

    def brake(self, q, dq, effort_scale, envs, out) -> None:
        """The computed-torque stop of the envs of ``envs`` ((envs,) bool) into ``out`` (envs,
        n) N m: each joint decelerates at up to ``deceleration`` times its drive's derating
        ``effort_scale`` (envs, n), held by a critically damped PD (:data:`HOLD_FREQUENCY`) at
        the estimate where the env's stop began (:attr:`hold`), ``tau = M(q) a + C(q, dq) dq +
        g(q)`` (Pinocchio's RNEA at ``q`` rad, ``dq`` rad/s), clipped to the derated effort
        limits and to the smoother's rate limit from the last committed torque
        (:attr:`command`)."""
        limit, w = self.robot.effort_limit, HOLD_FREQUENCY
        start = envs & ~self.braked
        self.hold[start] = q[start]
        self._braking[:] = envs
        for e in np.flatnonzero(envs):
            most = self.deceleration * effort_scale[e]
            a = np.clip(-2.0 * w * dq[e] - w * w * (q[e] - self.hold[e]), -most, most)
            tau = pin.rnea(self._model, self._data, q[e], dq[e], a)
            np.clip(tau, -limit * effort_scale[e], limit * effort_scale[e], out=out[e])
            last = self.command[e]
            np.clip(out[e], last - self._rate, last + self._rate, out=out[e])
