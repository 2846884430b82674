"""The floors of the tick: what the libraries the runtime calls cost on their own.

:class:`FloorLoop` times the library calls of a tick (``sim2real.deploy.runtime.STAGES`` wrap
them in the runtime's own work) alone, per tick, on objects of its own built from the same robot
and policy, so the tick benchmark sets each stage beside its floors in the same run: the
difference is the runtime's own work, the part a faster runtime can remove. The floors outside
physics add up to the least a tick can cost with these libraries.

Per tick (``FLOOR_STAGES``), for the runtime's ``envs`` envs:

- ``infer``: ``InferenceSession.run_with_iobinding`` of the policy's own session (the runtime's
  options: one thread, sequential, all graph optimizations) through a second binding of its
  own, observation and action ((envs, dim), one call for the batch) bound once (``OnnxPolicy``
  binds them the same way).
- ``ruckig``: ``Ruckig.update`` and ``pass_to_input`` of one ``Ruckig(envs * n, dt)`` (the
  smoother's one instance) with the robot's limits, its target moved each tick as a policy's is
  (a new trajectory each tick), the new position read back.
- ``fk``: per env, ``pinocchio.forwardKinematics`` and ``updateFramePlacement`` of the
  end-effector frame (what ``sim2real.deploy.core.state.Kinematics`` calls); a legged robot: the
  base estimator's calls, ``forwardKinematics`` of the floating-base configuration and velocity,
  each foot's ``updateFramePlacement`` and ``getFrameVelocity``.
- ``dynamics``: per env, the Pinocchio calls the guard's drive model makes every tick to check the
  smoother's motion (``MotionEnvelope.drive``, velocity control mode: ``computeGeneralizedGravity``
  and ``crba`` at the estimate; ``MotionEnvelope.torque``, torque control mode: ``aba``); 0 for a
  runtime without a drive model (position control mode).
- ``mj_step``: ``mujoco.mj_step(m, d, nstep=decimation)`` on a copy of the plant's first env,
  set before each call (untimed) to the plant's state and controls of the moment; 0 when built
  with ``physics=False`` (the campaign times its physics apart, on the plant's own models).
"""

from __future__ import annotations

import time

import mujoco
import numpy as np

FLOOR_STAGES = ("infer", "ruckig", "fk", "dynamics", "mj_step")
#: The floors outside the physics stage: the least a tick without physics costs.
FLOOR_OUTSIDE_PHYSICS = ("infer", "ruckig", "fk", "dynamics")
#: rad: the amplitude of the target's motion around the home pose (a small goal-reaching motion)
TARGET_AMPLITUDE = 0.2
#: ticks per period of the target's motion
TARGET_PERIOD = 500


class FloorLoop:
    """The library calls of one tick of ``rt``'s envs, each alone (see the module docstring).

    Args:
        rt: The runtime whose policy session, robot, guard and plant the floors are built from.
            Only the session is called (through a binding of its own); the rest is read.
        physics: Time ``mj_step`` too (False: its column stays 0).

    Attributes:
        samples: (ticks, 5) int64 ns per tick, the calls of ``FLOOR_STAGES``.
    """

    def __init__(self, rt, physics: bool = True):
        import onnxruntime as ort
        import pinocchio as pin
        from ruckig import InputParameter, OutputParameter, Ruckig

        robot, policy, backend = rt.robot, rt.policy, rt.backend
        self._pin = pin
        n, envs = robot.n_joints, rt.envs
        dofs = envs * n
        session = policy.session
        self._session = session
        self._binding = session.io_binding()
        self._obs = np.zeros((envs, policy.obs_dim), np.float32)
        self._act = np.zeros((envs, policy.act_dim), np.float32)
        self._values = [ort.OrtValue.ortvalue_from_numpy(a) for a in (self._obs, self._act)]
        self._binding.bind_ortvalue_input(policy.input_name, self._values[0])
        self._binding.bind_ortvalue_output(policy.output_name, self._values[1])
        self._ruckig = Ruckig(dofs, robot.control_period)
        self._inp, self._out = InputParameter(dofs), OutputParameter(dofs)
        self._inp.current_position = list(robot.home) * envs
        self._inp.current_velocity = [0.0] * dofs
        self._inp.current_acceleration = [0.0] * dofs
        self._inp.max_velocity = list(robot.soft_velocity_limit) * envs
        self._inp.max_acceleration = list(robot.acceleration_limit) * envs
        self._inp.max_jerk = list(robot.jerk_limit) * envs
        self._home = np.tile(np.asarray(robot.home, dtype=np.float64), envs)
        self._phase = np.tile(np.linspace(0.0, np.pi, n), envs)
        self._model = robot.pin_model
        self._data = self._model.createData()
        self._frame = robot.ee_frame_id
        self._rows = [np.asarray(rt.state.q[e]) for e in range(envs)]  # read at each call
        self._speeds = [np.asarray(rt.state.dq[e]) for e in range(envs)]
        self._feet = list(getattr(robot, "foot_frame_ids", ()) or ()) if self._frame < 0 else []
        self._q_full = self._v_full = None
        if self._model.nq != n:  # a floating base: the base estimator's call (base at the origin)
            self._q_full = pin.neutral(self._model)
            self._v_full = np.zeros(self._model.nv)
        envelope = getattr(rt.guard, "envelope", None)
        self._dynamics = None
        if envelope is not None and envelope.drive is not None:
            self._dynamics = "velocity"
        elif envelope is not None and getattr(envelope, "torque", None) is not None:
            self._dynamics = "torque"
        self._dyn_model = robot.fixed_base_model  # the drive models' own
        self._dyn_data = self._dyn_model.createData()
        self._zero_torque = np.zeros(n)
        self._physics = physics
        self._m = backend.models[0]
        self._live = backend.datas[0]
        self._d = mujoco.MjData(self._m)
        mujoco.mj_copyData(self._d, self._m, self._live)
        self._nstep = robot.decimation
        self._k = 0
        self.samples = np.zeros((0, len(FLOOR_STAGES)), dtype=np.int64)

    def run(self, ticks: int) -> np.ndarray:
        """Time ``ticks`` ticks of the calls; returns and appends to :attr:`samples` the
        (ticks, 5) ns."""
        pin, clock = self._pin, time.perf_counter_ns
        session, binding = self._session, self._binding
        ruckig, inp, out = self._ruckig, self._inp, self._out
        model, data, frame, rows = self._model, self._data, self._frame, self._rows
        q_full, v_full, feet = self._q_full, self._v_full, self._feet
        dyn, dyn_model, dyn_data = self._dynamics, self._dyn_model, self._dyn_data
        speeds, tau = self._speeds, self._zero_torque
        m, d, live, nstep, step = self._m, self._d, self._live, self._nstep, mujoco.mj_step
        physics = self._physics
        rec = np.zeros((ticks, len(FLOOR_STAGES)), dtype=np.int64)
        for i in range(ticks):
            self._k += 1
            s = np.sin(2 * np.pi * self._k / TARGET_PERIOD + self._phase)
            target = (self._home + TARGET_AMPLITUDE * s).tolist()
            self._obs[:, :] = 0.1 * s[0]
            if physics:
                d.qpos[:], d.qvel[:], d.ctrl[:] = live.qpos, live.qvel, live.ctrl
                d.act[:] = live.act
            t0 = clock()
            session.run_with_iobinding(binding)
            t1 = clock()
            inp.target_position = target
            ruckig.update(inp, out)
            _ = out.new_position
            out.pass_to_input(inp)
            t2 = clock()
            for q in rows:
                if q_full is None:
                    pin.forwardKinematics(model, data, q)
                else:
                    q_full[7:] = q
                    v_full[6:] = 0.0
                    pin.forwardKinematics(model, data, q_full, v_full)
                if frame >= 0:
                    pin.updateFramePlacement(model, data, frame)
                for f in feet:
                    pin.updateFramePlacement(model, data, f)
                    pin.getFrameVelocity(model, data, f, pin.LOCAL_WORLD_ALIGNED)
            t3 = clock()
            if dyn == "velocity":
                for q in rows:
                    pin.computeGeneralizedGravity(dyn_model, dyn_data, q)
                    pin.crba(dyn_model, dyn_data, q)
            elif dyn == "torque":
                for q, dq in zip(rows, speeds, strict=True):
                    pin.aba(dyn_model, dyn_data, q, dq, tau)
            t4 = clock()
            if physics:
                step(m, d, nstep=nstep)
            t5 = clock()
            rec[i] = (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4 if physics else 0)
        self.samples = np.concatenate([self.samples, rec])
        return rec
