"""The policy's own loop (:class:`OwnLoop`): a policy run as its own stack's simulation loop runs
it, in place of our runtime.

Each tick reads the plant's true state (no sensor noise, no estimator: the joints, a floating
base's pose and velocity, the gait clock at the loop's time), builds the observation as the
policy's contract says, and sends the policy's targets to the drives as emitted (no guard, no
smoother, no stop): the loops of unitree_rl_gym's ``deploy_mujoco.py`` and unitree_rl_lab's
sim2sim. The plant is anything with ``true_position``, ``true_velocity``, ``true_base_state``
(a floating base), ``write`` and ``advance``: :class:`~sim2real.deploy.backends.sim.plant.SimBackend`
(its position-mode drives), or a bare MuJoCo model whose torque actuators take the PD law at
every physics step (the push benchmark's, :class:`sim2real.stacks.loops.bare.BarePlant`).

The loop keeps its own ``ticks``, ``time`` (s) and ``mode`` (always RUNNING): what the world's
schedules read of a runtime (:class:`~sim2real.eval.world.pushes.DomainPushes`, a
:class:`~sim2real.deploy.tasks.commands.CommandSchedule`, which writes ``velocity_command``). The
soak's fall replay runs it from a captured runtime's state
(:mod:`sim2real.eval.soak.fall_replay`); the push benchmark beside our runtime
(:mod:`bench.push_loops`).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING


class OwnLoop:
    """The policy's own loop over ``plant`` (module docstring).

    Args:
        policy: Callable ``(envs, obs_dim) float32 -> (envs, n) float32`` with a ``spec``
            (:class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy`).
        plant: The true state's source and the drives (module docstring).
        state: The :class:`~sim2real.deploy.core.state.RobotState` the observation reads, written
            with the truth at each tick (its other fields, a velocity command, foot contacts,
            a clip, are the caller's); (envs, n).
        goal: (envs, 3) m, the observation's goal (an arm's; zeros for a legged robot).
        dt: s, the control period.
        time, ticks: Where the loop's clock starts (s, and its tick count).
        injector: Optional :class:`~sim2real.deploy.backends.sim.faults.FaultInjector`: its
            plant-side faults (a force armed) switched at each tick's time.
        base: Optional callable ``base(state)`` run after the truth is written and before the
            observation is built: what the loop's policy sees of the base in place of the
            truth (the push benchmark's loop fed the runtime's base estimate,
            ``bench.push_loops.plant_loop``); None: the truth.

    Attributes:
        ticks, time: Ticks run (from ``ticks``) and the clock (s). mode: (envs,) int8, RUNNING.
        velocity_command: A legged state's command (envs, 3) (``state.command``), or None.
    """

    def __init__(
        self, policy, plant, state, goal, dt: float, time=0.0, ticks=0, injector=None, base=None
    ):
        self.policy, self.spec, self.plant = policy, policy.spec, plant
        self.state, self.goal, self.dt, self.injector = state, goal, dt, injector
        self.base = base
        self.time, self.ticks = time, ticks
        envs, n = state.q.shape
        self.mode = np.full(envs, RUNNING, dtype=np.int8)
        self.velocity_command = state.command
        self._obs = np.zeros((envs, self.spec.obs_dim), dtype=np.float32)
        self._target = np.zeros((envs, n))
        self._truth = np.zeros((envs, 13)) if state.base is not None else None

    def act(self, t: float | None = None) -> np.ndarray:
        """The policy's targets from the true state at time ``t`` (s; default the loop's),
        written to the plant; returns them, (envs, n) in the units of the plant's mode (a view,
        overwritten by the next call). The policy's action becomes the state's last action."""
        state, plant = self.state, self.plant
        state.q[:] = plant.true_position()
        state.dq[:] = plant.true_velocity()
        if self._truth is not None:  # a floating base: its true pose and velocity, the clock
            state.base.set_truth(plant.true_base_state(out=self._truth))
            state.clock[:] = self.time if t is None else t
            if self.base is not None:
                self.base(state)
        self.spec.observation(state, self.goal, out=self._obs)
        action = self.policy(self._obs)
        self.spec.action_to_target(action, state, out=self._target)
        plant.write(self._target)
        state.last_action[:] = action
        return self._target

    def advance(self) -> None:
        """One control period of the plant on the written targets; the clock moves on, and a
        phase-clocked policy's motion time (``state.motion_time``: the loop is always RUNNING,
        its motion plays on)."""
        self.plant.advance()
        self.ticks += 1
        self.time += self.dt
        if self.state.motion_time is not None:
            self.state.motion_time += self.dt

    def tick(self) -> None:
        """One tick: the fault injector's plant-side faults at the loop's time, :meth:`act`,
        :meth:`advance`."""
        if self.injector is not None:
            self.injector.before_read(self.time)
        self.act()
        self.advance()
