"""The MuJoCo plant's state dict: what a checkpoint of a
:class:`~sim2real.deploy.backends.sim.plant.SimBackend`
holds, taken and loaded.

A plant's state is its per-env arrays (the drive command and torque, the derated effort limits,
the joint sensors' settings and latency buffers, the last sensor frame, the thermal nodes, and a
floating base's IMU and contact state), MuJoCo's own state of each env (``mjSTATE_INTEGRATION``,
the warning counters and the friction that drift edits), the tick and the sensor streams; the
conventions are :mod:`sim2real.deploy.core.stateful`'s.

:class:`SimState` is a base class of :class:`~sim2real.deploy.backends.sim.plant.SimBackend`; its methods
work on the backend's attributes (set in ``SimBackend.__init__``).
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.deploy.core.stateful import check, env_index, env_list, from_json, put, scalar, take

#: MuJoCo's state a plant's ``state_dict`` keeps: everything a step reads (time, qpos, qvel, act,
#: warm start, ctrl, applied forces, mocap, equality flags, user data, plugin state).
_MJ_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


class SimState:
    """The state dict of a :class:`~sim2real.deploy.backends.sim.plant.SimBackend` (module docstring)."""

    #: Per env, the ground of a plant whose floor is not the plane z = 0: an object with
    #: ``height_at(x, y) -> m`` (:class:`sim2real.eval.world.terrain.GroundMap`, set by whoever
    #: laid the terrain into the env's model); None (default): every env on the plane.
    grounds: list | None = None

    def ground_height(self, truth: np.ndarray) -> np.ndarray:
        """(envs,) m, the ground's height under each env's true base (``truth`` (envs, 13),
        :meth:`true_base_state`): its ground's (:attr:`grounds`), 0 on the plane."""
        out = np.zeros(len(truth))
        for e, ground in enumerate(self.grounds or ()):
            if ground is not None:
                out[e] = float(ground.height_at(truth[e, 0], truth[e, 1]))
        return out

    # ------------------------------------------------------------------ state
    def _state_fields(self) -> dict[str, np.ndarray]:
        """The plant's per-env arrays, env axis first (the latency buffers are (slots, envs, ...)
        inside: views with the env axis moved to the front)."""
        f, th = self.frame, self.thermal
        return {
            "command": self._command,
            "torque": self._torque,
            "effort_limit": self.effort_limit,
            **self._joint_sensors.state_fields(),
            "frame/time": f.time,
            "frame/position": f.position,
            "frame/position_stamp": f.position_stamp,
            "frame/winding_temperature": f.winding_temperature,
            "frame/temperature_stamp": f.temperature_stamp,
            "thermal/winding_temperature": th.winding_temperature,
            "thermal/housing_temperature": th.housing_temperature,
            "thermal/current": th.current,
            "thermal/power": th.power,
            "thermal/ambient": th.ambient,
            **(self._base_sensors.state_fields() if self._base_sensors is not None else {}),
            **self.actuators.state_fields(),
        }

    def _mujoco_fields(self) -> dict[str, np.ndarray]:
        """Copies of MuJoCo's per-env state, (envs, ...): ``mj_getState`` of
        ``mjSTATE_INTEGRATION`` (time, qpos, qvel, act, warm start, ctrl, applied forces, ...),
        the warning counters and the model's ``dof_frictionloss`` (drift edits it)."""
        states, warnings, friction = [], [], []
        for m, d in zip(self.models, self.datas, strict=True):
            state = np.empty(mujoco.mj_stateSize(m, _MJ_STATE))
            mujoco.mj_getState(m, d, state, _MJ_STATE)
            states.append(state)
            warnings.append(d.warning.number.copy())
            friction.append(m.dof_frictionloss.copy())
        return {
            "mujoco/state": np.stack(states),
            "mujoco/warnings": np.stack(warnings),
            "mujoco/dof_frictionloss": np.stack(friction),
        }

    def state_dict(self, env: int | None = None) -> dict:
        """The plant's state (copies; conventions of :mod:`sim2real.deploy.core.stateful`).

        Per env, env axis first (length 1 for one env ``env``): ``mujoco/state`` (MuJoCo's
        ``mjSTATE_INTEGRATION``), ``mujoco/warnings``, ``mujoco/dof_frictionloss``; the drive
        ``command`` and ``torque`` (N m), ``effort_limit`` (N m), the sensor settings
        ``noise_sigma`` (rad), ``dropout_probability``, ``latency_ticks``; the latency buffers
        ``buffer/position`` (envs, slots, n) rad and ``buffer/stamp`` (envs, slots) s; the last
        ``frame/<field>`` (a drive repeats its temperature between reports); the thermal nodes
        ``thermal/<field>`` (degC, A, W). Shared: ``tick`` (int) and ``sensor_rng``, JSON of the
        sensor streams' ``bit_generator.state`` (a list over the envs with
        :meth:`~sim2real.deploy.backends.sim.plant.SimBackend.set_sensor_streams`, the batch's one stream
        otherwise).
        """
        out: dict = take(self._state_fields(), env)
        index = env_index(env)
        out.update({k: v[index] for k, v in self._mujoco_fields().items()})
        out["tick"] = int(self.tick)
        out["sensor_rng"] = self._joint_sensors.stream_state(env)
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``), into a backend built
        with the same robot, mode and models (the same kind of sensor streams). MuJoCo's state
        is set without ``mj_forward`` (which would rewrite the warm start); the drives' torque
        limits are derated afresh from the thermal state at the next
        :meth:`~sim2real.deploy.backends.sim.plant.SimBackend.advance`.

        Raises:
            StateDictError: a missing field, a shape that differs (a MuJoCo state of another
                model), or sensor streams of another kind; nothing is changed.
        """
        fields = self._state_fields()
        mj = self._mujoco_fields()
        check({**fields, **mj}, state, env)
        tick = scalar(state, "tick", int)
        envs = env_list(self.envs, env)
        rng = from_json(state, "sensor_rng")
        self._joint_sensors.check_stream_state(rng, envs)
        put(fields, state, env)
        for i, e in enumerate(envs):
            m, d = self.models[e], self.datas[e]
            mujoco.mj_setState(m, d, np.asarray(state["mujoco/state"][i]), _MJ_STATE)
            d.warning.number[:] = state["mujoco/warnings"][i]
            m.dof_frictionloss[:] = state["mujoco/dof_frictionloss"][i]
            self._derated[e] = True  # re-derate from the loaded winding temperatures
        self.tick = tick
        self._joint_sensors.load_stream_state(rng, envs)
        self.true_position()  # the gathered joint angles follow the loaded state
        self.true_velocity()
