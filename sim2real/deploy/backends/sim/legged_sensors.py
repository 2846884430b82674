"""IMU and foot-contact sensing of a floating-base robot in the MuJoCo plant.

:class:`BaseSensorModel` belongs to a :class:`sim2real.deploy.backends.sim.plant.SimBackend` of a robot
with a ``[base]`` table; it reads MuJoCo's sensors of the robot's MJCF (``gyro`` and ``accelerometer``
at the IMU site, a ``touch`` per foot site: the normal force of the contacts inside the site)
and turns them into what a real robot's drivers deliver, at each sensor's own rate and latency:

IMU (``[sensors.imu]``, Kalibr's IMU noise model, per axis, sample period ``dt``)::

    b_k = b_(k-1) + walk sqrt(dt) N(0, 1)       (b_0 ~ N(0, bias_sigma^2), the turn-on bias)
    y_k = true_k + b_k + sigma N(0, 1)

for the gyroscope (rad/s) and the accelerometer (specific force, m/s^2), both in the IMU site's
frame; a reading is lost with probability ``dropout``. An IMU with ``orientation_sigma`` also
sends its own attitude (its onboard filter, ``_onboard_attitude`` below): the IMU site's true
attitude relative to gravity, turned by a roll and pitch error (each a Gauss-Markov process)
and, with ``heading_rate_sigma``, by a heading error about gravity that drifts as a 6-axis
AHRS's does::

    h_k = h_(k-1) + r dt + heading_walk sqrt(dt) N(0, 1)   (h_0 = 0, r ~ N(0, heading_rate_sigma^2)
                                                           drawn at turn-on, then held)

reported ``Rz(h) R_xy(roll, pitch error) q_site`` (world frame, ``w x y z``). Foot contact
(``[sensors.contact]``): each foot's normal force plus Gaussian noise (N),
``foot_contact = force > threshold``. MuJoCo computes the sensors at the start of each physics
step: a reading is the state one physics timestep before the end of the control period.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.deploy.backends.sim import legged_sensors_kernel as kernel
from sim2real.deploy.backends.sim.sensors import draw
from sim2real.deploy.core.attitude import align_up, quat_multiply, rotation_quaternions
from sim2real.deploy.kernels import differs
from sim2real.deploy.kernels.calls import bind
from sim2real.robots import Robot


def sensor_address(model: mujoco.MjModel, kind, site: int) -> int:
    """``sensordata`` address of the ``kind`` (``mjtSensor``) sensor at site ``site``.

    Raises:
        ValueError: the model has no such sensor there.
    """
    for k in range(model.nsensor):
        if (
            model.sensor_type[k] == kind
            and model.sensor_objtype[k] == mujoco.mjtObj.mjOBJ_SITE
            and model.sensor_objid[k] == site
        ):
            return int(model.sensor_adr[k])
    raise ValueError(f"the model has no {kind} sensor at site {model.site(site).name}")


#: :data:`~.legged_sensors_kernel.READ`'s names of the frame's IMU and contact fields.
_FRAME_FIELDS = (
    "angular", "acceleration", "orientation", "imu_stamp", "foot_force", "foot_contact",
    "contact_stamp",
)  # fmt: skip


class BaseSensorModel:
    """IMU and contact sensors of ``backend`` (a :class:`~sim2real.deploy.backends.sim.plant.SimBackend` of a
    floating-base robot).

    The noise settings are per env (``(envs,)`` arrays, change them between ticks: per-session
    randomization, :func:`sim2real.eval.world.sensors.apply_imu`). The draws come from the
    backend's sensor stream(s), after the encoder's, so an arm's readings are unchanged.

    The plant's tick samples and reads through the compiled kernels of
    :mod:`sim2real.deploy.backends.sim.legged_sensors_kernel` (the same numbers), drawing from the
    streams of the plant's compiled step; the numpy path (:attr:`compiled` False, a stream that
    is not a numpy ``Generator``, a sample of some envs) is their reference.

    Attributes (per env, ``(envs,)``; change between ticks, in place: the compiled tick is
    bound to these arrays):
        gyro_noise_sigma (rad/s), accel_noise_sigma (m/s^2), gyro_bias_sigma (rad/s),
        accel_bias_sigma (m/s^2), gyro_bias_walk (rad/s/sqrt(s)), accel_bias_walk
        (m/s^2/sqrt(s)), imu_dropout, imu_latency_ticks (int), force_noise_sigma (N),
        contact_threshold (N), contact_latency_ticks (int).
        gyro_bias, accel_bias: (envs, 3) the present biases (ground truth).

    Raises:
        ValueError: a latency above the backend's ``max_latency_ticks``, a sensor rate above the
            control rate, or a model without the sensors.
    """

    def __init__(self, backend, robot: Robot):
        imu, contact = robot.config.sensors.imu, robot.config.sensors.contact
        self.backend, self.robot = backend, robot
        envs, nf = backend.envs, robot.n_feet
        self.envs, self.n_feet = envs, nf
        rate = 1.0 / robot.control_period
        for name, value in (("sensors.imu.rate", imu.rate), ("sensors.contact.rate", contact.rate)):
            if value > rate * (1 + 1e-9):
                raise ValueError(
                    f"{robot.directory / 'robot.toml'}: field '{name}' = {value} Hz is above the "
                    f"control rate {rate:g} Hz (one reading a tick at most)"
                )
        for name, value in (
            ("sensors.imu.latency_ticks", imu.latency_ticks),
            ("sensors.contact.latency_ticks", contact.latency_ticks),
        ):
            if value > backend.max_latency_ticks:
                raise ValueError(
                    f"{name} = {value} exceeds max_latency_ticks = {backend.max_latency_ticks}"
                )
        self.imu_every = max(1, int(round(rate / imu.rate)))
        self.contact_every = max(1, int(round(rate / contact.rate)))

        def full(value, dtype=np.float64):
            return np.full(envs, value, dtype=dtype)

        self.gyro_noise_sigma = full(imu.gyro_noise_sigma)
        self.accel_noise_sigma = full(imu.accel_noise_sigma)
        self.gyro_bias_sigma = full(imu.gyro_bias_sigma)
        self.accel_bias_sigma = full(imu.accel_bias_sigma)
        self.gyro_bias_walk = full(imu.gyro_bias_walk)
        self.accel_bias_walk = full(imu.accel_bias_walk)
        self.imu_dropout = full(imu.dropout)
        self.imu_latency_ticks = full(imu.latency_ticks, np.int64)
        self.force_noise_sigma = full(contact.force_noise_sigma)
        self.contact_threshold = full(contact.threshold)
        self.contact_latency_ticks = full(contact.latency_ticks, np.int64)
        self.gyro_bias = np.zeros((envs, 3))
        self.accel_bias = np.zeros((envs, 3))
        #: the IMU sends its own attitude (``[sensors.imu] orientation_sigma`` set)
        self.has_orientation = imu.orientation_sigma is not None
        self.orientation_sigma = full(imu.orientation_sigma or 0.0)
        self.orientation_tau = full(imu.orientation_tau)
        #: (envs, 2) rad, the onboard attitude's present roll and pitch errors (ground truth;
        #: world-frame rotation about x and y)
        self.orientation_error = np.zeros((envs, 2))
        self._noise2 = np.empty((envs, 2))
        #: the onboard attitude's heading drifts (``[sensors.imu] heading_rate_sigma`` set)
        self.has_heading = self.has_orientation and imu.heading_rate_sigma is not None
        self.heading_rate_sigma = full(imu.heading_rate_sigma or 0.0)
        self.heading_walk = full(imu.heading_walk)
        #: (envs,) rad/s, the onboard filter's residual yaw-rate bias (ground truth; drawn at
        #: each reset); heading_error: (envs,) rad, its heading's present error about gravity
        self.heading_rate = np.zeros(envs)
        self.heading_error = np.zeros(envs)
        self._noise1 = np.empty((envs, 1))
        self._site_quat = np.array(backend.models[0].site_quat[robot.imu_site_id], dtype=float)
        # an AHRS's attitude is relative to gravity: the world turned so that gravity is -z (a
        # model without gravity has no up: the world's own frame)
        g = np.array(backend.models[0].opt.gravity, dtype=float)
        norm = float(np.linalg.norm(g))
        self._gravity_frame = align_up(-g / norm) if norm > 0 else np.array([1.0, 0, 0, 0])

        m = backend.models[0]
        gyro = sensor_address(m, mujoco.mjtSensor.mjSENS_GYRO, robot.imu_site_id)
        acc = sensor_address(m, mujoco.mjtSensor.mjSENS_ACCELEROMETER, robot.imu_site_id)
        touch = [sensor_address(m, mujoco.mjtSensor.mjSENS_TOUCH, s) for s in robot.foot_site_ids]
        self._gyro, self._acc, self._touch = slice(gyro, gyro + 3), slice(acc, acc + 3), touch
        size = backend.max_latency_ticks + 1
        self._buf_imu = np.full((size, envs, 10), np.nan)  # gyro, accel, attitude
        self._buf_imu_stamp = np.full((size, envs), np.nan)
        self._buf_force = np.full((size, envs, nf), np.nan)
        self._buf_contact_stamp = np.full((size, envs), np.nan)
        self._noise3 = np.empty((envs, 3))
        self._noise6 = np.empty((envs, 6))
        self._noise_f = np.empty((envs, nf))
        self._true_imu = np.empty((envs, 6))
        self._true_force = np.empty((envs, nf))
        self._env_index = np.arange(envs)
        #: False: numpy's path only (the reference of the compiled tick)
        self.compiled = True
        # the compiled tick: each env's MjData addresses (bound with the plant's compiled step,
        # which a new model or a copy of the plant builds anew), the correlation of the attitude
        # error (numpy's exp), the calls and what they were bound to
        self._data = np.zeros((envs, 2), dtype=np.int64)
        self._nsensor, self._nq = int(m.nsensordata), int(m.nq)
        self._touch_index = np.array(touch, dtype=np.int64)
        self._ratio, self._a = np.zeros(envs), np.zeros(envs)
        # the correlation times ``_a`` was computed from (NaN: not yet), their test (_tau_differs)
        self._tau_seen, self._tau_changed = np.full(envs, np.nan), None
        self._sample_call = self._read_call = self._sample_key = self._read_key = None
        self._bind_sample(None, np.zeros((envs, 3), dtype=np.int64))  # compiled (or loaded) now
        self._bind_read(backend.frame if hasattr(backend, "frame") else None)
        self._sample_key = self._read_key = None
        differs(np.zeros(1), np.zeros(1))  # compiled (or loaded) now, not at the first tick

    def __getstate__(self) -> dict:
        """A copy (``copy.deepcopy``, pickle) holds no bound call nor ``MjData`` address (the
        plant's, which the copy builds anew): it binds its own at its first compiled tick."""
        state = dict(self.__dict__)
        state["_sample_call"] = state["_read_call"] = None
        state["_sample_key"] = state["_read_key"] = state["_tau_changed"] = None
        state["_data"] = np.zeros_like(self._data)
        return state

    # ------------------------------------------------------------------ ground truth
    def true_imu(self) -> np.ndarray:
        """(envs, 6) the noiseless gyroscope (rad/s) and accelerometer (m/s^2) of the last
        physics step, IMU site frame (evaluation only)."""
        for e, d in enumerate(self.backend.datas):
            self._true_imu[e, :3] = d.sensordata[self._gyro]
            self._true_imu[e, 3:] = d.sensordata[self._acc]
        return self._true_imu

    def true_foot_force(self) -> np.ndarray:
        """(envs, n_feet) N, the noiseless normal contact force of each foot (evaluation only)."""
        for e, d in enumerate(self.backend.datas):
            self._true_force[e] = d.sensordata[self._touch]
        return self._true_force

    # ------------------------------------------------------------------ lifecycle
    def reset(self, which: np.ndarray, full: bool) -> None:
        """Draw the turn-on biases of the envs ``which`` (bool (envs,)); ``full``: clear every
        buffer (the backend's clock restarts); else clear those envs' readings and take one now
        (MuJoCo's sensors were computed by ``mj_forward`` at the reset pose)."""
        draw(self.backend.joint_sensors.rng, "standard_normal", self._noise6, which)
        self.gyro_bias[which] = (self._noise6[:, :3] * self.gyro_bias_sigma[:, None])[which]
        self.accel_bias[which] = (self._noise6[:, 3:] * self.accel_bias_sigma[:, None])[which]
        if self.has_orientation:  # the onboard filter's error starts in its stationary spread
            draw(self.backend.joint_sensors.rng, "standard_normal", self._noise2, which)
            start = self._noise2 * self.orientation_sigma[:, None]
            self.orientation_error[which] = start[which]
        if self.has_heading:  # the filter's heading restarts at the truth's; its rate bias anew
            draw(self.backend.joint_sensors.rng, "standard_normal", self._noise1, which)
            self.heading_rate[which] = (self._noise1[:, 0] * self.heading_rate_sigma)[which]
            self.heading_error[which] = 0.0
        if full:
            for buf in (self._buf_imu, self._buf_imu_stamp, self._buf_force):
                buf.fill(np.nan)
            self._buf_contact_stamp.fill(np.nan)
            return
        for buf in (self._buf_imu, self._buf_imu_stamp, self._buf_force, self._buf_contact_stamp):
            buf[:, which] = np.nan
        tick, time = self.backend.tick, self.backend.time
        self.sample(tick, time, force=True, envs=which)
        self._rested(which, tick, time)

    def _rested(self, which: np.ndarray, tick: int, time: float) -> None:
        """The latency buffers of the envs ``which`` as if the robot had rested at its reset pose:
        every earlier slot holds the reading just taken, stamped ``j`` control periods before
        ``time`` for the slot ``j`` ticks back. Without it the IMU's next ``latency`` readings
        were missing and a loop kept the attitude read before the reset (the soak's stand-up:
        the heading of the robot lying on the floor, to which a motion clip was aligned)."""
        size = self._buf_imu_stamp.shape[0]
        now = tick % size
        dt = self.robot.control_period
        for j in range(1, size):
            slot = (tick - j) % size
            self._buf_imu[slot, which] = self._buf_imu[now, which]
            self._buf_imu_stamp[slot, which] = self._buf_imu_stamp[now, which] - j * dt
            self._buf_force[slot, which] = self._buf_force[now, which]
            self._buf_contact_stamp[slot, which] = self._buf_contact_stamp[now, which] - j * dt

    # ------------------------------------------------------------------ per tick
    def sample(
        self, tick: int, time: float, force: bool = False, envs: np.ndarray | None = None
    ) -> None:
        """Take the readings due at control tick ``tick`` (s ``time``) into the latency buffers:
        the IMU every ``imu_every`` ticks, the foot forces every ``contact_every`` ticks
        (``force``: both now, for the envs ``envs`` only when given). Every env at its ticks:
        one compiled call (:func:`~sim2real.deploy.backends.sim.legged_sensors_kernel.
        base_sample`) drawing from the streams of the plant's compiled step, when they are
        numpy ``Generator`` streams (else numpy's path, the same numbers)."""
        if self.compiled and not force and envs is None:
            step = self.backend.compiled_step
            if step is not None:
                if step.rng is not self.backend.joint_sensors.rng:  # new streams
                    step.bind_streams()
                if step.draws:
                    self._sample(step, tick, time)
                    return
        self.reference_sample(tick, time, force, envs)

    def _sample(self, step, tick: int, time: float) -> None:
        """:meth:`sample` of every env by the compiled call, bound to ``step`` (the plant's
        :class:`~sim2real.deploy.backends.sim.compiled_step.CompiledStep`: its streams, and the
        plant's ``MjData`` of its time)."""
        if step is not self._sample_key:
            self._bind_sample(step, step.streams)
        imu_due = tick % self.imu_every == 0
        if imu_due and self.has_orientation and self._tau_differs():
            dt = self.imu_every * self.robot.control_period
            np.exp(np.divide(-dt, self.orientation_tau, out=self._ratio), out=self._a)
            np.copyto(self._tau_seen, self.orientation_tau)
        slot = tick % self._buf_imu_stamp.shape[0]
        self._sample_call(imu_due, tick % self.contact_every == 0, slot, time)

    def _tau_differs(self) -> bool:
        """Whether ``orientation_tau`` changed since ``_a`` (numpy's exp, as the numpy path has it)
        was computed from it (one compiled comparison, :func:`sim2real.deploy.kernels.differs`)."""
        tau, bound = self.orientation_tau, self._tau_changed
        if bound is None or bound[0] is not tau:
            ok = isinstance(tau, np.ndarray) and tau.dtype == np.float64 and tau.ndim == 1
            if not ok or tau.shape != self._tau_seen.shape:
                return True  # not an array the comparison takes: numpy's exp every time
            bound = self._tau_changed = (tau, bind(differs, tau, self._tau_seen))
        return bound[1]()

    def _bind_sample(self, step, streams: np.ndarray) -> None:
        """Bind the compiled sample to ``streams`` ((envs, 3), ``step``'s), the plant's present
        ``MjData`` (each env's ``sensordata`` and ``qpos`` addresses) and the model's arrays.

        Raises:
            ValueError: an env whose model's sensors or joints differ in size from the first's; an
                array of the model not of its :data:`~.legged_sensors_kernel.SAMPLE` field.
        """
        for e, d in enumerate(self.backend.datas):
            if d.sensordata.shape != (self._nsensor,) or d.qpos.shape != (self._nq,):
                raise ValueError(f"env {e}: its model's sensors or joints differ from env 0's")
            self._data[e, kernel.SENSORDATA] = d.sensordata.ctypes.data
            self._data[e, kernel.QPOS] = d.qpos.ctypes.data
        self._sample_key = step
        values = dict(
            nsensor=self._nsensor, nq=self._nq, gyro=self._gyro.start, acc=self._acc.start,
            has_orientation=self.has_orientation, dt=self.imu_every * self.robot.control_period,
            has_heading=self.has_heading, heading_rate=self.heading_rate,
            heading_walk=self.heading_walk, heading_error=self.heading_error, noise1=self._noise1,
            streams=streams, data=self._data, touch=self._touch_index, a=self._a,
            gyro_bias=self.gyro_bias, accel_bias=self.accel_bias,
            gyro_bias_walk=self.gyro_bias_walk, accel_bias_walk=self.accel_bias_walk,
            gyro_noise_sigma=self.gyro_noise_sigma, accel_noise_sigma=self.accel_noise_sigma,
            orientation_error=self.orientation_error, orientation_sigma=self.orientation_sigma,
            site_quat=self._site_quat, gravity_frame=self._gravity_frame,
            dropout=self.imu_dropout, force_noise_sigma=self.force_noise_sigma,
            noise6=self._noise6, noise2=self._noise2, noise_f=self._noise_f,
            buf_imu=self._buf_imu, buf_imu_stamp=self._buf_imu_stamp, buf_force=self._buf_force,
            buf_contact_stamp=self._buf_contact_stamp,
        )  # fmt: skip
        table = kernel.SAMPLE.pack_or_none(**values)
        if table is None:
            raise ValueError(f"the IMU and contact model: {kernel.SAMPLE.mismatch(values)}")
        self._sample_call = bind(kernel.base_sample, table, rest=(True, True, 0, 0.0))

    def reference_sample(
        self, tick: int, time: float, force: bool = False, envs: np.ndarray | None = None
    ) -> None:
        """:meth:`sample` by numpy (the compiled call's reference)."""
        size = self._buf_imu_stamp.shape[0]
        slot = tick % size
        rng = self.backend.joint_sensors.rng
        sel = slice(None) if envs is None else envs
        if force or tick % self.imu_every == 0:
            dt = self.imu_every * self.robot.control_period
            root = np.sqrt(dt)
            draw(rng, "standard_normal", self._noise6, envs)
            self.gyro_bias[sel] += (self._noise6[:, :3] * (self.gyro_bias_walk * root)[:, None])[
                sel
            ]
            self.accel_bias[sel] += (self._noise6[:, 3:] * (self.accel_bias_walk * root)[:, None])[
                sel
            ]
            draw(rng, "standard_normal", self._noise6, envs)
            reading = np.full((self.envs, 10), np.nan)
            reading[:, :6] = self.true_imu()
            reading[:, :3] += self.gyro_bias + self._noise6[:, :3] * self.gyro_noise_sigma[:, None]
            reading[:, 3:6] += (
                self.accel_bias + self._noise6[:, 3:] * self.accel_noise_sigma[:, None]
            )
            if self.has_orientation:
                reading[:, 6:] = self._onboard_attitude(dt, envs)
            stamp = np.full(self.envs, time)
            lost = draw(rng, "random", np.ones((self.envs, 1)), envs) < self.imu_dropout[:, None]
            reading[lost[:, 0]] = np.nan
            stamp[lost[:, 0]] = np.nan
            self._buf_imu[slot, sel] = reading[sel]
            self._buf_imu_stamp[slot, sel] = stamp[sel]
        elif envs is None:
            self._buf_imu[slot] = np.nan
            self._buf_imu_stamp[slot] = np.nan
        if force or tick % self.contact_every == 0:
            draw(rng, "standard_normal", self._noise_f, envs)
            reading = self.true_foot_force() + self._noise_f * self.force_noise_sigma[:, None]
            self._buf_force[slot, sel] = reading[sel]
            self._buf_contact_stamp[slot, sel] = time
        elif envs is None:
            self._buf_force[slot] = np.nan
            self._buf_contact_stamp[slot] = np.nan

    def _onboard_attitude(self, dt: float, envs) -> np.ndarray:
        """(envs, 4) the IMU's own attitude after ``dt`` s: each roll and pitch error steps its
        Gauss-Markov process (``e' = a e + sqrt(1 - a^2) sigma N(0, 1)``, ``a = exp(-dt / tau)``;
        only the envs ``envs`` when given) and turns the IMU site's true attitude (relative to
        gravity) about the world's x and y axes; with a drifting heading (``has_heading``), the
        heading error steps (``h' = h + r dt + walk sqrt(dt) N(0, 1)``) and turns it about the
        world's z axis after (module docstring)."""
        draw(self.backend.joint_sensors.rng, "standard_normal", self._noise2, envs)
        a = np.exp(-dt / self.orientation_tau)[:, None]
        step = a * self.orientation_error + np.sqrt(1 - a * a) * (
            self._noise2 * self.orientation_sigma[:, None]
        )
        sel = slice(None) if envs is None else envs
        self.orientation_error[sel] = step[sel]
        site = quat_multiply(self.backend.true_base_state()[:, 3:7], self._site_quat[None])
        site = quat_multiply(np.broadcast_to(self._gravity_frame, site.shape), site)
        error = np.zeros((self.envs, 3))
        error[:, :2] = self.orientation_error
        attitude = quat_multiply(rotation_quaternions(error), site)
        if not self.has_heading:
            return attitude
        draw(self.backend.joint_sensors.rng, "standard_normal", self._noise1, envs)
        step = self.heading_error + (
            self.heading_rate * dt + self.heading_walk * np.sqrt(dt) * self._noise1[:, 0]
        )
        self.heading_error[sel] = step[sel]
        turn = np.zeros((self.envs, 3))
        turn[:, 2] = self.heading_error
        return quat_multiply(rotation_quaternions(turn), attitude)

    def read(self, frame, tick: int) -> None:
        """Fill the frame's IMU and contact fields with the readings arriving at ``tick``: one
        compiled call (:func:`~sim2real.deploy.backends.sim.legged_sensors_kernel.base_read`)
        bound to ``frame`` (numpy's path where the frame's fields do not fit it)."""
        if self.compiled:
            if frame is not self._read_key:
                self._bind_read(frame)
            if self._read_call is not None:
                self._read_call(tick)
                return
        self.reference_read(frame, tick)

    def _bind_read(self, frame) -> None:
        """Bind the compiled read to ``frame``'s fields (None: to arrays of their types, to
        compile it now); no call where a field is not a C-contiguous array of its shape."""
        envs, nf = self.envs, self.n_feet
        if frame is None:
            f8 = (np.zeros((envs, 3)), np.zeros((envs, 3)), np.zeros((envs, 4)), np.zeros(envs))
            fields = (*f8, np.zeros((envs, nf)), np.zeros((envs, nf), bool), np.zeros(envs))
        else:
            fields = (
                frame.imu_angular_velocity, frame.imu_acceleration, frame.imu_orientation,
                frame.imu_stamp, frame.foot_force, frame.foot_contact, frame.contact_stamp,
            )  # fmt: skip
        self._read_key = frame
        self._read_call = None
        table = kernel.READ.pack_or_none(
            buf_imu=self._buf_imu, buf_imu_stamp=self._buf_imu_stamp, buf_force=self._buf_force,
            buf_contact_stamp=self._buf_contact_stamp, imu_latency=self.imu_latency_ticks,
            contact_latency=self.contact_latency_ticks, threshold=self.contact_threshold,
            **dict(zip(_FRAME_FIELDS, fields, strict=True)),
        )  # fmt: skip
        if table is not None:
            self._read_call = bind(kernel.base_read, table, rest=(0,))

    def reference_read(self, frame, tick: int) -> None:
        """:meth:`read` by numpy (the compiled call's reference)."""
        size = self._buf_imu_stamp.shape[0]
        idx = self._env_index
        origin = tick - self.imu_latency_ticks
        slot = origin % size
        imu = self._buf_imu[slot, idx]
        frame.imu_angular_velocity[:] = imu[:, :3]
        frame.imu_acceleration[:] = imu[:, 3:6]
        frame.imu_orientation[:] = imu[:, 6:]
        frame.imu_stamp[:] = self._buf_imu_stamp[slot, idx]
        early = origin < 0
        if early.any():
            frame.imu_angular_velocity[early] = np.nan
            frame.imu_acceleration[early] = np.nan
            frame.imu_orientation[early] = np.nan
            frame.imu_stamp[early] = np.nan
        origin = tick - self.contact_latency_ticks
        slot = origin % size
        frame.foot_force[:] = self._buf_force[slot, idx]
        frame.contact_stamp[:] = self._buf_contact_stamp[slot, idx]
        early = origin < 0
        if early.any():
            frame.foot_force[early] = np.nan
            frame.contact_stamp[early] = np.nan
        with np.errstate(invalid="ignore"):
            np.greater(frame.foot_force, self.contact_threshold[:, None], out=frame.foot_contact)

    def state_fields(self) -> dict[str, np.ndarray]:
        """Per-env arrays of the sensor state, env axis first (for the backend's
        ``state_dict``): settings, biases and latency buffers."""
        return {
            "imu/gyro_noise_sigma": self.gyro_noise_sigma,
            "imu/accel_noise_sigma": self.accel_noise_sigma,
            "imu/gyro_bias_sigma": self.gyro_bias_sigma,
            "imu/accel_bias_sigma": self.accel_bias_sigma,
            "imu/gyro_bias_walk": self.gyro_bias_walk,
            "imu/accel_bias_walk": self.accel_bias_walk,
            "imu/dropout": self.imu_dropout,
            "imu/latency_ticks": self.imu_latency_ticks,
            "imu/gyro_bias": self.gyro_bias,
            "imu/accel_bias": self.accel_bias,
            "imu/orientation_sigma": self.orientation_sigma,
            "imu/orientation_tau": self.orientation_tau,
            "imu/orientation_error": self.orientation_error,
            "imu/heading_rate_sigma": self.heading_rate_sigma,
            "imu/heading_walk": self.heading_walk,
            "imu/heading_rate": self.heading_rate,
            "imu/heading_error": self.heading_error,
            "imu/buffer": np.moveaxis(self._buf_imu, 1, 0),
            "imu/buffer_stamp": np.moveaxis(self._buf_imu_stamp, 1, 0),
            "contact/force_noise_sigma": self.force_noise_sigma,
            "contact/threshold": self.contact_threshold,
            "contact/latency_ticks": self.contact_latency_ticks,
            "contact/buffer": np.moveaxis(self._buf_force, 1, 0),
            "contact/buffer_stamp": np.moveaxis(self._buf_contact_stamp, 1, 0),
        }
