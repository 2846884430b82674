"""The simulated robot ("plant"): MuJoCo physics, the drives, motor heat; its sensors composed in.

One :class:`SimBackend` drives ``envs`` copies of a robot in lockstep (the runtime's batch axis),
each with its own ``MjData`` and, where the soak harness randomizes dynamics, its own ``MjModel``.
Per control tick: ``read()``, ``write(command)`` and ``advance()``, which runs ``decimation``
physics steps and integrates the two-node motor thermal model.

Composed of stage objects with their own state, to which it delegates by name (data by
:func:`~sim2real.deploy.core.delegate.delegate`, methods by ``forward``): the encoders and temperature reports
(:mod:`.sensors`), a floating base's IMU and foot contact (:mod:`.legged_sensors`), the drives
(:mod:`.drives`), the thermal and actuator models, the pushes and forces (:mod:`.disturbances`),
the true state, for evaluation only (:mod:`.truth`); the state dict gathers theirs (:mod:`.state`).
``advance`` runs these models in two compiled calls around ``mj_step``
(:mod:`sim2real.deploy.backends.sim.plant_kernel`; their table:
:mod:`~sim2real.deploy.backends.sim.compiled_step`).
Interfaces: :class:`~sim2real.deploy.core.backend.Backend` (lifecycle calls are no-ops) and
:class:`~sim2real.deploy.core.backend.SimulatedPlant` (ground truth, fault hooks, external forces).

Errors: MuJoCo's autoreset is disabled and its warning counters are read after every ``advance``:
a divergence raises :class:`SimulationDivergedError`. A non-finite command raises
:class:`NonFiniteCommandError` and never reaches MuJoCo.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from sim2real.deploy.backends.sim.actuators import ActuatorModel
from sim2real.deploy.backends.sim.compiled_step import CompiledStep
from sim2real.deploy.backends.sim.disturbances import SimDisturbances
from sim2real.deploy.backends.sim.divergence import (  # noqa: F401 - the errors importable here
    WARNING_SLICE,
    NonFiniteCommandError,
    SimulationDivergedError,
    check_divergence,
)
from sim2real.deploy.backends.sim.drives import SimDrives
from sim2real.deploy.backends.sim.legged_sensors import BaseSensorModel
from sim2real.deploy.backends.sim.plant_faces import plant_extras
from sim2real.deploy.backends.sim.plant_kernel import (
    DERATE,
    DRAW,
    DRAWN,
    NO_SAMPLE,
    STALE,
)
from sim2real.deploy.backends.sim.sensors import JointSensorModel
from sim2real.deploy.backends.sim.state import MujocoState, PlantState
from sim2real.deploy.backends.sim.stepping import quiet_sensors, step_period
from sim2real.deploy.backends.sim.truth import TrueState
from sim2real.deploy.core.backend import BackendLifecycle, SensorFrame
from sim2real.deploy.core.delegate import delegate, forward
from sim2real.deploy.kernels import all_finite, copy_finite
from sim2real.deploy.kernels.calls import bind
from sim2real.robots import CONTROL_MODES, Robot
from sim2real.robots.thermal import TwoNodeThermalModel


class SimBackend(BackendLifecycle):
    """MuJoCo plant with sensor and motor-thermal models, batched over ``envs``.

    Args:
        robot: The robot description.
        mode: Control mode, 'position' (rad), 'velocity' (rad/s, a drive's PI velocity loop with
            anti-windup, which holds the joint at zero command; see ``Robot.mjspec``) or 'torque'
            (N m); default from robot.toml.
        envs: Number of robots simulated in lockstep.
        seed: Seed of the sensor noise and dropout streams (``numpy.random.PCG64``).
        models: Optional compiled models, one per env (randomized dynamics). They must come from
            ``robot.mjspec(mode)``. Default: one model shared by all envs.
        max_latency_ticks: Capacity of the latency buffer; ``latency_ticks`` may be raised up to it
            at run time (fault injection).

    Attributes (per-env sensor settings; change them between ticks to inject faults):
        noise_sigma: (envs,) rad. dropout_probability: (envs,). latency_ticks: (envs,) int.
        joint_sensors, drives, disturbances, thermal, actuators, truth: its stages (module
            docstring); grounds: the grounds under the envs (:class:`TrueState`).
    """

    # the true state, for evaluation only; the grounds under the envs (None: the plane)
    true_position = forward("truth", "position")
    true_velocity = forward("truth", "velocity")
    true_base_state = forward("truth", "base_state")
    end_effector_position = forward("truth", "end_effector_position")
    ground_height = forward("truth", "ground_height")
    grounds = delegate("truth", "grounds", writable=True)
    # the joint sensors' settings and streams (write the arrays in place to inject faults)
    noise_sigma = delegate("joint_sensors", "noise_sigma")
    encoder_bias = delegate("joint_sensors", "encoder_bias")
    dropout_probability = delegate("joint_sensors", "dropout_probability")
    latency_ticks = delegate("joint_sensors", "latency_ticks")
    max_latency_ticks = delegate("joint_sensors", "max_latency_ticks")
    encoder_quantum = delegate("joint_sensors", "encoder_quantum")
    temperature_resolution = delegate("joint_sensors", "temperature_resolution")
    encoder_every = delegate("joint_sensors", "encoder_every")
    set_sensor_streams = forward("joint_sensors", "set_streams")
    # the drives: present torque limits (envs, n) N m and their derating
    effort_limit = delegate("drives", "effort_limit")
    derating = delegate("drives", "derating")
    # the pushes and forces (SimulatedPlant's fault hooks)
    set_base_velocity = forward("disturbances", "set_base_velocity")
    push_base = forward("disturbances", "push_base")
    push_wrench = forward("disturbances", "push_wrench")
    set_push_wrench = forward("disturbances", "set_push_wrench")
    set_base_wrench = forward("disturbances", "set_base_wrench")
    set_external_force = forward("disturbances", "set_external_force")
    free_base = delegate("disturbances", "free_base")

    def __init__(
        self,
        robot: Robot,
        mode: str | None = None,
        envs: int = 1,
        seed: int = 0,
        models: Sequence[mujoco.MjModel] | None = None,
        max_latency_ticks: int = 32,
    ):
        mode = robot.control_mode if mode is None else mode
        if mode not in CONTROL_MODES:
            raise ValueError(f"control mode '{mode}' is unknown; expected one of {CONTROL_MODES}")
        if envs < 1:
            raise ValueError(f"envs must be >= 1, got {envs}")
        self.robot, self.mode, self.envs = robot, mode, envs
        n = self.n_joints = robot.n_joints
        models = [robot.plant_model(mode)] * envs if models is None else models
        if len(models) != envs:
            raise ValueError(f"models: expected {envs} models (one per env), got {len(models)}")
        self._nu = n * robot.actuators_per_joint(mode)
        # a floating base: MuJoCo's free joint comes first (qpos 7, qvel 6, one joint)
        self._qpos_offset, self._qvel_offset = robot.qpos_offset, robot.qvel_offset
        for m in models:
            self._check_model(m, "models")
        self.models = list(models)
        self.datas = [mujoco.MjData(m) for m in self.models]
        self.disturbances = SimDisturbances(robot, self.models, self.datas)
        self._jnt_offset = 1 if self.free_base else 0  # the model's free joint (disturbances)
        self._views: list[tuple] = [()] * envs
        self._quiet = [False] * envs  # each env's model's stepping.quiet_sensors (see _bind)
        self._qvel_views: list[np.ndarray] = [np.zeros(0)] * envs  # the joints' qvel (see _bind)
        #: the drives: derated torque limits, anti-windup (velocity mode)
        self.drives = SimDrives(robot, mode, envs, self.models, self.free_base)
        self._compiled: CompiledStep | None = None  # built below, once every array exists
        #: the motors' torque-speed lines and command delays, applied every physics step
        self.actuators = ActuatorModel(
            robot, envs, robot.control_period / robot.decimation, robot.decimation
        )
        self._stepwise = self.actuators.active  # physics one step at a time
        self._actfrc: list[np.ndarray] = [np.zeros((n, 2))] * envs  # jnt_actfrcrange rows
        for e in range(envs):
            self._bind(e)
        self.decimation = robot.decimation
        self.control_period = robot.control_period

        self.frame = SensorFrame.empty(envs, n, robot.n_feet if self.free_base else None)
        #: encoders and temperature reports (settings, latency buffers, the sensor streams)
        self.joint_sensors = JointSensorModel(robot, envs, self.frame, seed, max_latency_ticks)

        self.thermal = TwoNodeThermalModel(
            robot.motors, envs, robot.config.sensors.ambient_temperature
        )
        self._command = np.zeros((envs, n))
        # write's last array, and the one its compiled copy is bound to (write)
        self._written = self._write_source = self._write_bound = None
        copy_finite(self._command, self._command.copy())  # compiled now, not in a tick
        self._qpos = np.zeros((envs, n))
        self._qvel = np.zeros((envs, n))
        self._torque = np.zeros((envs, n))
        self.tick = 0
        #: the true state (evaluation only), over the views and into the gathered joint state
        self.truth = TrueState(
            robot, self.datas, self._views, self._qvel_views, self._qpos, self._qvel, self.free_base
        )
        #: IMU and foot contact of a floating-base robot (per-env noise settings, biases,
        #: ground truth; None for an arm): its kind's face
        self.base_sensors: BaseSensorModel | None = plant_extras(self, robot)
        parts = {"drives": self.drives, "sensors": self.joint_sensors, "thermal": self.thermal}
        parts |= {"base": self.base_sensors, "actuators": self.actuators}
        mj = MujocoState(self.models, self.datas)
        self._state = PlantState(self._command, self._torque, self.frame, parts, mj)
        #: the table of the compiled step (sim2real.deploy.backends.sim.plant_kernel)
        self._compiled = CompiledStep(self)
        self.reset()

    # ------------------------------------------------------------------ lifecycle
    def reset(
        self,
        q: np.ndarray | None = None,
        envs: np.ndarray | None = None,
        base_offset: np.ndarray | None = None,
    ) -> None:
        """Put envs at rest at ``q`` (rad, (n,) or (envs, n); default the home pose).

        ``base_offset`` ((envs, 3) m, world; a free-floating base only): each reset env's base
        is put that far from its MJCF pose (a robot carried to another spot of its ground: a
        curriculum walk's respawn, :mod:`sim2real.eval.soak.curriculum_walk`).

        With ``envs`` None every env is reset: the clock returns to 0, the motors cool to ambient
        and the sensor buffers are cleared. With a boolean mask ``envs`` (shape (envs,)) only those
        envs restart (a training episode): the shared clock runs on, their motors cool to ambient
        and their sensor history reads the new pose, as if the robot had rested there.

        The initial command holds the pose: q in position mode (0 rad/s for a velocity-driven
        joint), 0 rad/s in velocity mode, the gravity torque in torque mode.
        """
        q0 = np.broadcast_to(
            self.robot.home if q is None else np.asarray(q, float), (self.envs, self.n_joints)
        )
        which = np.ones(self.envs, dtype=bool) if envs is None else np.asarray(envs, dtype=bool)
        for e in np.nonzero(which)[0]:
            m, d = self.models[e], self.datas[e]
            mujoco.mj_resetData(m, d)  # a floating base: at its MJCF pose (standing)
            d.qpos[self._qpos_offset :] = q0[e]
            if base_offset is not None:
                d.qpos[:3] += base_offset[e]
            if m.na:  # integrating velocity servos start their setpoint at the pose
                d.act[:] = q0[e]
            mujoco.mj_forward(m, d)
            if self.mode == "position":  # a velocity drive (a wheel) holds speed 0
                self._command[e] = np.where(self.robot.velocity_driven, 0.0, q0[e])
            elif self.mode == "velocity":
                self._command[e] = 0.0
            else:
                self._command[e] = d.qfrc_bias[self._qvel_offset :]
            self._views[e][2][:] = self._command[e]
        self.actuators.reset(which, self._command)
        if self.free_base:
            self.base_sensors.reset(which, envs is None)
        if envs is None:
            self.thermal.reset()
            self.joint_sensors.clear()
            self.tick = 0
            self.true_position()  # sample_sensors reads the gathered joint angles
            self.sample_sensors()
            return
        self.thermal.winding_temperature[which] = self.thermal.ambient[which]
        self.thermal.housing_temperature[which] = self.thermal.ambient[which]
        self.joint_sensors.restart(which, q0[which], self.time, self.thermal.ambient)

    def set_model(self, env: int, model: mujoco.MjModel) -> None:
        """Give ``env`` a new compiled model (randomized dynamics; from ``robot.mjspec(mode)``)
        and fresh ``MjData``; call :meth:`reset` for that env afterwards.

        Raises:
            ValueError: the model's joint or actuator count differs from the robot's.
        """
        self._check_model(model, "model")
        self.models[env] = model
        self.datas[env] = mujoco.MjData(model)
        self._bind(env)

    def _check_model(self, m: mujoco.MjModel, what: str) -> None:
        nq = self.n_joints + self.robot.qpos_offset
        if m.nq != nq or m.nu != self._nu:
            raise ValueError(
                f"{what}: expected nq = {nq} and nu = {self._nu} ({self.mode} mode), "
                f"got nq={m.nq}, nu={m.nu}"
            )

    def _bind(self, e: int) -> None:
        """Cache env ``e``'s model, data and the views the hot path touches (ctrl as
        (actuators per joint, n): every actuator of a joint takes its command; qpos; the joint
        actuator torque ``qfrc_actuator``, clamped to the effort limit; divergence warning
        counters), so that the hot path does not look them up on MjData each tick."""
        m, d = self.models[e], self.datas[e]
        self.drives.bind(e, m, d)  # re-derate at the next advance; velocity mode: the setpoints
        ctrl = d.ctrl.reshape(-1, self.n_joints)
        qpos, force = d.qpos[self._qpos_offset :], d.qfrc_actuator[self._qvel_offset :]
        self._views[e] = (m, d, ctrl, qpos, force, d.warning.number[WARNING_SLICE])
        self._quiet[e] = quiet_sensors(m)
        self._qvel_views[e] = d.qvel[self._qvel_offset :]
        self._actfrc[e] = m.jnt_actfrcrange[self._jnt_offset : self._jnt_offset + self.n_joints]
        if self._compiled is not None:  # the kernels' addresses of the new views
            self._compiled = CompiledStep(self)

    def kernel_arrays(self) -> dict[str, np.ndarray]:
        """The plant's live arrays, by name, for its compiled step, which keeps their addresses
        (:class:`~sim2real.deploy.backends.sim.compiled_step.CompiledStep`): the arrays
        themselves, not copies, C-contiguous, never rebound.

        (envs, n) float64: ``command`` (units of the mode), ``qpos`` (rad), ``qvel`` (rad/s) and
        ``torque`` (N m), the joint state gathered at the end of a period; ``lag`` (rad, the
        velocity loop's setpoints' scratch) and ``windup_bound`` (rad, ``effort_limit / kp``).
        (envs,) bool: ``derated`` (an env whose model may hold a derated limit) and ``hot`` (an
        env with a winding above its derating start). Raises nothing.
        """
        dr = self.drives
        return {
            "command": self._command, "qpos": self._qpos, "qvel": self._qvel,
            "torque": self._torque, "lag": dr.lag, "windup_bound": dr.windup_bound,
            "derated": dr.derated, "hot": dr.hot,
        }  # fmt: skip

    def env_views(self, env: int) -> dict:
        """Env ``env``'s ``model`` and ``data`` and the live views of them the step touches
        (valid until :meth:`set_model` gives the env another model): ``ctrl`` (actuators per
        joint, n), the joints' ``qpos`` (n,) rad, ``qvel`` (n,) rad/s and ``force``
        (``qfrc_actuator``, (n,) N m), ``warnings`` (the divergence warnings' counters,
        MuJoCo's ``mjWarningStat`` rows), ``act`` (velocity mode: the drives' setpoints, rad;
        else empty) and ``actfrc`` (the joints' ``jnt_actfrcrange`` rows, (n, 2) N m).

        Raises:
            IndexError: ``env`` outside the batch.
        """
        m, d, ctrl, qpos, force, warnings = self._views[env]
        return {
            "model": m, "data": d, "ctrl": ctrl, "qpos": qpos, "qvel": self._qvel_views[env],
            "force": force, "warnings": warnings, "act": self.drives.acts[env],
            "actfrc": self._actfrc[env],
        }  # fmt: skip

    @property
    def time(self) -> float:
        """Plant clock, s (identical for every env)."""
        return self.tick * self.control_period

    # ------------------------------------------------------------------ the Backend lifecycle
    def open(self) -> None:
        """Nothing to connect: the plant is ready from construction (``Backend`` contract)."""

    def close(self) -> None:
        """Nothing to release (``Backend`` contract)."""

    def enable(self) -> None:
        """The simulated drives are always on (``Backend`` contract)."""

    def disable(self) -> None:
        """The simulated drives have no torque-off state (``Backend`` contract)."""

    def drive_errors(self) -> None:
        """The simulated drives report no hardware errors: None (``Backend`` contract)."""
        return None

    def describe_drive_error(self, joint: int, bits: int) -> str:
        """``Backend`` contract; the simulated drives report none."""
        return f"joint {self.robot.joint_names[joint]}: error bits {bits:#04x}"

    # ------------------------------------------------------------------ the three calls
    def read(self) -> SensorFrame:
        """The sensor frame of the current tick (see :class:`SensorFrame`).

        The frame is overwritten by the next read: copy what you keep.
        """
        f = self.frame
        f.time.fill(self.tick * self.control_period)  # self.time
        self.joint_sensors.read(self.tick)
        if self.base_sensors is not None:
            self.base_sensors.read(f, self.tick)
        return f

    def write(self, command: np.ndarray) -> None:
        """Set the command of every env: (envs, n_joints) in the units of the control mode.

        An array written twice in a row (a runtime's command buffer) is then copied by one
        compiled call bound to it (:func:`~sim2real.deploy.kernels.copy_finite`), same checks.

        Raises:
            ValueError: wrong shape.
            NonFiniteCommandError: any NaN or inf; the previous command stays in force.
        """
        if command is self._write_source and self._write_bound():  # else raises below
            return
        written = command
        command = np.asarray(command, dtype=np.float64)
        if command.shape != self._command.shape:
            raise ValueError(f"command: expected shape {self._command.shape}, got {command.shape}")
        if not all_finite(command):
            raise NonFiniteCommandError(
                f"command rejected at t={self.time:.4f} s: non-finite values in envs "
                f"{np.unique(np.nonzero(~np.isfinite(command))[0]).tolist()}"
            )
        self._command[:] = command
        if written is command and written is self._written:  # the same buffer again: bind it
            self._write_bound = bind(copy_finite, command, self._command)
            self._write_source = command
        self._written = written

    def advance(self) -> None:
        """Run one control period: ``decimation`` physics steps per env, then the thermal model
        and the sensors.

        The plant's own models run in two compiled calls around MuJoCo's steps
        (:mod:`sim2real.deploy.backends.sim.plant_kernel`): the commands (or the actuators'
        start of the period) and the derating screen before; the joint state, divergence
        screen, anti-windup, thermal step and encoder sample with its draws after. A derating
        that is due, the temperature reports and a floating base's IMU and contact stay in
        Python. With motors that delay their command or follow a torque-speed line the physics
        runs one step at a time, each after one compiled call for the env's actuators.

        Raises:
            SimulationDivergedError: MuJoCo flagged a bad state in any env (every env has
                stepped; the thermal and sensor models have not, the streams have not drawn
                unless they are not numpy Generators).
        """
        compiled, nstep = self._compiled, self.decimation
        tick = self.tick
        status = compiled.before(tick)  # before_physics(table, tick)
        if status & STALE:  # a copied plant: views of its own MjData, its own table
            self._compiled = None
            for e in range(self.envs):
                self._bind(e)
            self._compiled = compiled = CompiledStep(self)
            status = compiled.before(tick)
        if status & DERATE:
            self.drives.set_derated_limits(self.thermal.winding_temperature)
        # the sensors in the last step only; with delayed commands or a torque range that
        # follows the joint speed one step at a time (actuator_substep(table, e, tick, sub))
        substep = compiled.substep if self._stepwise else None
        step_period(self._views, self._quiet, nstep, substep, tick)
        tick += 1
        sensors = self.joint_sensors
        sample = NO_SAMPLE
        if tick % sensors.encoder_every == 0:
            if sensors.rng is not compiled.rng:  # new streams (set_sensor_streams)
                compiled.bind_streams()
            if compiled.draws:
                sample = DRAW
            else:
                sensors.draw(tick)
                sample = DRAWN
        if not compiled.after(tick, sample):  # MuJoCo found a bad state (and reset the data)
            for e, d in enumerate(self.datas):
                check_divergence(e, d)
        self.tick = tick
        if tick % sensors.temperature_every == 0:
            sensors.report_temperature(self.time, self.thermal.winding_temperature)
        if self.base_sensors is not None:
            self.base_sensors.sample(tick, self.time)

    # ------------------------------------------------------------------ evaluation only
    def joint_torque(self) -> np.ndarray:
        """(envs, n_joints) N m, actuator torque at the end of the last control period."""
        return self._torque

    @property
    def compiled_step(self) -> CompiledStep | None:
        """The table and bound calls of the plant's compiled step (built anew for a new model
        of an env and in a copy of the plant; None while the plant is being built)."""
        return self._compiled

    def state_dict(self, env: int | None = None) -> dict:
        """The plant's state, its stages' and MuJoCo's (copies; :meth:`PlantState.state_dict
        <sim2real.deploy.backends.sim.state.PlantState.state_dict>` lists the fields)."""
        return self._state.state_dict(self.tick, env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``), into a backend built
        with the same robot, mode and models (the same kind of sensor streams). MuJoCo's state
        is set without ``mj_forward``; the drives' torque limits are derated afresh from the
        thermal state at the next :meth:`advance`.

        Raises:
            StateDictError: a missing field, a shape that differs, or sensor streams of another
                kind; nothing is changed.
        """
        self.tick = self._state.load_state_dict(state, env)
        self.true_position()  # the gathered joint angles follow the loaded state
        self.true_velocity()

    def stale_context(self, env: int = 0) -> dict:
        """What the plant's encoders of env ``env`` do now (:meth:`JointSensorModel.stale_context`)."""
        return self.joint_sensors.stale_context(env, getattr(self, "engine", "mujoco"))

    # ------------------------------------------------------------------ internals
    def check_divergence(self, env: int) -> None:
        """Raise :class:`SimulationDivergedError` if MuJoCo flagged env ``env``'s state as
        diverged (warning counters) or its ``qpos``/``qvel`` are not finite; else nothing."""
        check_divergence(env, self.datas[env])

    def sample_sensors(self) -> None:
        """Take the readings due at this tick from the joint angles gathered by the last period
        (or :meth:`true_position`): the encoders and temperature reports, then the IMU and foot
        contact (in this order from the sensor streams). The step of the Python path before the
        compiled one (:func:`sim2real.deploy.backends.sim.reference.reference_advance`, the
        pybullet plant); :meth:`advance` samples by itself. Raises nothing."""
        q = self._qpos  # gathered by advance (or reset)
        dq = self.true_velocity() if self.joint_sensors.has_velocity else None
        self.joint_sensors.sample(self.tick, self.time, q, self.thermal.winding_temperature, dq)
        if self.base_sensors is not None:
            self.base_sensors.reference_sample(self.tick, self.time)
