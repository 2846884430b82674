"""The MuJoCo plant's state dict: what a checkpoint of a
:class:`~sim2real.deploy.backends.sim.plant.SimBackend` holds, taken and loaded.

A plant's state is its per-env arrays (the drive command and torque, the drives' derated effort
limits, the joint sensors' settings and latency buffers, the last sensor frame, the thermal
nodes, and a floating base's IMU and contact state: each stage's fields, gathered by the plant),
MuJoCo's own state of each env (:class:`MujocoState`: ``mjSTATE_INTEGRATION``, the warning
counters and the friction that drift edits), the tick and the sensor streams; the conventions
are :mod:`sim2real.deploy.core.stateful`'s. :class:`PlantState` takes and loads it from those
parts; the plant's ``state_dict`` and ``load_state_dict`` delegate to it.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.deploy.core.stateful import check, env_index, env_list, from_json, put, scalar, take

#: MuJoCo's state a plant's ``state_dict`` keeps: everything a step reads (time, qpos, qvel, act,
#: warm start, ctrl, applied forces, mocap, equality flags, user data, plugin state).
_MJ_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


class MujocoState:
    """MuJoCo's own state of each env of a plant, over its ``models`` and ``datas`` (one
    ``MjModel`` and ``MjData`` per env: the plant's lists, which it shares)."""

    def __init__(self, models: list, datas: list):
        self.models, self.datas = models, datas

    def state_fields(self) -> dict[str, np.ndarray]:
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

    def load(self, state: dict, envs: list[int]) -> None:
        """Set the envs ``envs`` (rows of ``state``'s ``mujoco/*``, checked) without
        ``mj_forward`` (which would rewrite the warm start)."""
        for i, e in enumerate(envs):
            m, d = self.models[e], self.datas[e]
            mujoco.mj_setState(m, d, np.asarray(state["mujoco/state"][i]), _MJ_STATE)
            d.warning.number[:] = state["mujoco/warnings"][i]
            m.dof_frictionloss[:] = state["mujoco/dof_frictionloss"][i]


class PlantState:
    """A plant's state dict over its parts (module docstring): its ``command`` and ``torque``
    ((envs, n) arrays), its sensor ``frame``, its ``stages`` (``drives``, ``sensors``: the
    joint sensors, ``thermal``, ``base``: the base sensors or None, ``actuators``) and MuJoCo's
    state ``mj``; the tick is the plant's (given and returned)."""

    def __init__(self, command, torque, frame, stages: dict, mj: MujocoState):
        self.command, self.torque, self.frame, self.mj = command, torque, frame, mj
        self.drives, self.sensors, self.thermal = (
            stages["drives"],
            stages["sensors"],
            stages["thermal"],
        )
        self.base, self.actuators = stages["base"], stages["actuators"]

    def fields(self) -> dict[str, np.ndarray]:
        """The plant's per-env arrays and its stages', env axis first (the latency buffers are
        (slots, envs, ...) inside: views with the env axis moved to the front)."""
        f, th, base = self.frame, self.thermal, self.base
        return {
            "command": self.command, "torque": self.torque, **self.drives.state_fields(),
            **self.sensors.state_fields(),
            "frame/time": f.time, "frame/position": f.position,
            "frame/position_stamp": f.position_stamp,
            "frame/winding_temperature": f.winding_temperature,
            "frame/temperature_stamp": f.temperature_stamp,
            "thermal/winding_temperature": th.winding_temperature,
            "thermal/housing_temperature": th.housing_temperature,
            "thermal/current": th.current, "thermal/power": th.power, "thermal/ambient": th.ambient,
            **(base.state_fields() if base is not None else {}), **self.actuators.state_fields(),
        }  # fmt: skip

    def state_dict(self, tick: int, env: int | None = None) -> dict:
        """The plant's state at ``tick`` (copies; conventions of
        :mod:`sim2real.deploy.core.stateful`).

        Per env, env axis first (length 1 for one env ``env``): ``mujoco/state`` (MuJoCo's
        ``mjSTATE_INTEGRATION``), ``mujoco/warnings``, ``mujoco/dof_frictionloss``; the drive
        ``command`` and ``torque`` (N m), ``effort_limit`` (N m), the sensor settings
        ``noise_sigma`` (rad), ``dropout_probability``, ``latency_ticks``; the latency buffers
        ``buffer/position`` (envs, slots, n) rad and ``buffer/stamp`` (envs, slots) s; the last
        ``frame/<field>`` (a drive repeats its temperature between reports); the thermal nodes
        ``thermal/<field>`` (degC, A, W). Shared: ``tick`` (int) and ``sensor_rng``, JSON of the
        sensor streams' ``bit_generator.state`` (a list over the envs with
        :meth:`~sim2real.deploy.backends.sim.plant.SimBackend.set_sensor_streams`, the batch's
        one stream otherwise).
        """
        out: dict = take(self.fields(), env)
        index = env_index(env)
        out.update({k: v[index] for k, v in self.mj.state_fields().items()})
        out["tick"] = int(tick)
        out["sensor_rng"] = self.sensors.stream_state(env)
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> int:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``); returns the tick
        (the plant's to set). The drives' limits are derated afresh at the next period.

        Raises:
            StateDictError: a missing field, a shape that differs (a MuJoCo state of another
                model), or sensor streams of another kind; nothing is changed.
        """
        fields = self.fields()
        check({**fields, **self.mj.state_fields()}, state, env)
        tick = scalar(state, "tick", int)
        envs = env_list(len(self.mj.models), env)
        rng = from_json(state, "sensor_rng")
        self.sensors.check_stream_state(rng, envs)
        put(fields, state, env)
        self.mj.load(state, envs)
        self.drives.derated[envs] = True  # re-derate from the loaded winding temperatures
        self.sensors.load_stream_state(rng, envs)
        return tick
