"""The rig's after-tick work as one compiled call (:class:`FusedAfterTick`), for a simulated
robot: the monitors' screens, the goal scheduler's tick and ``deploy-run``'s motion figures
(:func:`sim2real.deploy.rig.after_tick_kernel.after_tick`), with Python acting only where the
call says (coal, a flagged violation, a moved intervention counter, a goal due or reached). A
legged robot's estimation monitor and task (velocity commands) stay Python's, after the call in
the monitors' and the task's order; its motion figures (which neither changes) are in the call.

The call's table holds the addresses of the arrays the stages expose (``kernel_arrays()`` of the
monitors, the goal scheduler, the plant and its thermal model; ``env_views`` of the plant's envs)
and is used only while they stay the same objects (:meth:`FusedAfterTick.ready`); the rig builds
another when they change (a plant's env given another model). A run it does not fit (an arm
with another task, a legged robot without a base estimate, a plant whose truth is read
otherwise) keeps the monitors' own calls.
"""

from __future__ import annotations

import time

import numpy as np

from sim2real.deploy.core.latency import BIN_NS, BINS
from sim2real.deploy.core.modes import RUNNING, SAFE_STOP
from sim2real.deploy.kernels.calls import bind, put
from sim2real.deploy.rig import after_tick_kernel as ak

#: The plant's methods whose truth the call reads from its views (a plant overriding one of them
#: is not fused).
_TRUTH = ("true_position", "true_velocity", "joint_torque", "end_effector_position")


class FusedAfterTick:
    """One compiled call of a rig's monitors, goals and motion figures per tick.

    Build it with :meth:`build` (None when the rig's run does not fit). Per tick: :meth:`ready`,
    then the call (:meth:`__call__`).

    Attributes:
        motion: The rig's first hook is its :class:`~sim2real.deploy.rig.rig.MotionHook`, whose
            work (and timing, as the hook's) the call does with ``motion``.
    """

    def __init__(self, rig, table: np.ndarray, arrays: list, datas: list, motion: bool):
        """(:meth:`build` builds it.)"""
        self.rig, self.runtime, self.backend = rig, rig.runtime, rig.backend
        self._table, self._arrays, self._datas = table, arrays, datas
        self._mode, self._goal = rig.runtime.mode, rig.runtime.goal
        self.motion = motion
        #: a legged robot: the estimation monitor and the task run in Python after the call
        self._legged = rig.lies_down
        from sim2real.deploy.tasks.velocity import VelocityTask

        #: the legged task takes the truth the estimation monitor read (one read a tick)
        self._task_truth = self._legged and type(rig.task) is VelocityTask
        goals = rig.task is not None and not self._legged
        self._scheduler = rig.task.scheduler if goals else None
        self._q, self._dq, self._tau = arrays[0], arrays[1], arrays[2]
        self._stamp = arrays[3]  # the clock's scratch, the end of the monitors' screens
        rest = (0.0, 0, 1.0, True, 1.0, 0.1, True, True)
        self._call = bind(ak.after_tick, table, rest=rest)

    @classmethod
    def build(cls, rig, motion_hook=None) -> FusedAfterTick | None:
        """The call over ``rig``'s arrays, or None: a run that is not a simulated robot judged
        on its truth (a fixed base with a goal task or none; a legged robot lying down after its
        stops, ``Runtime.damping``, with a base estimate), or an array of another dtype, shape or
        layout than the kernel's. ``motion_hook``: the rig's first hook, its
        :class:`~sim2real.deploy.rig.rig.MotionHook` (its work joins the call), or None."""
        from sim2real.deploy.backends.sim.plant import SimBackend
        from sim2real.deploy.tasks.goals import GoalTask

        backend, task, runtime = rig.backend, rig.task, rig.runtime
        legged = rig.lies_down  # its envs lying down: ticks counted apart
        if (
            rig.violations is None
            or (not legged and rig.estimation is not None)
            or not isinstance(backend, SimBackend)
            or any(getattr(type(backend), m) is not getattr(SimBackend, m) for m in _TRUTH)
            or not (legged or task is None or type(task) is GoalTask)
            or runtime.backend is not backend
        ):
            return None
        if legged:
            task = None  # Python's, after the call
        motion = motion_hook is not None and bool(rig.hooks) and rig.hooks[0] is motion_hook
        envs, n = rig.envs, rig.robot.n_joints
        table, arrays = np.zeros(ak.size(envs), dtype=np.int64), []
        f8, i8, b1, e = np.float64, np.int64, np.bool_, (envs, n)
        plant = backend.kernel_arrays()
        v, iv = rig.violations.kernel_arrays(), rig.interventions.kernel_arrays()
        pairs, rows = v["clearance"].shape[1], iv["guard"].shape[0]
        margin = rig.violations.screen_margin
        dt = motion_hook.dt if motion else 0.0
        entries = [
            (ak.Q, plant["qpos"], f8, e),
            (ak.DQ, plant["qvel"], f8, e),
            (ak.TAU, plant["torque"], f8, e),
            (ak.STAMP, np.zeros(3, dtype=i8), i8, (3,)),
            (ak.PARAMS, np.array([margin, dt], dtype=f8), f8, (2,)),
            (ak.V_EE, v["ee"], f8, (envs, 3)),
            (ak.V_OFFSET_Q, v["offset_q"], f8, (n,)),
            (ak.V_OFFSET_EE, v["offset_ee"], f8, (3,)),
            (ak.V_BOUND, v["bound"], f8, (3 * n + 3,)),
            (ak.V_CHECKED_Q, v["checked_q"], f8, e),
            (ak.V_CLEARANCE, v["clearance"], f8, (envs, pairs)),
            (ak.V_WEIGHTS, v["pair_weights"], f8, (pairs, n)),
            (ak.V_TMP, v["tmp"], f8, e),
            (ak.V_NEED, v["need"], b1, (envs,)),
            (ak.V_DOWN, v["down"], b1, (envs,)),
            (ak.V_TICKS, v["ticks"], i8, (1,)),
            (ak.I_GUARD, iv["guard"], i8, (rows, envs)),
            (ak.I_PREV_GUARD, iv["previous_guard"], i8, (rows, envs)),
            (ak.I_STOPPING, iv["stopping"], i8, e),
            (ak.I_CLAMPS, iv["clamps"], i8, e),
            (ak.I_PREV_SMOOTHER, iv["previous_smoother"], i8, (2, envs, n)),
            (ak.I_TICKS, iv["ticks"], i8, (1,)),
            (ak.M_COUNTS, rig.monitor_cost.counts, i8, (1, BINS + 1)),
            (ak.M_MAX, rig.monitor_cost.max_ns, i8, (1,)),
            (ak.MODE, runtime.mode, np.int8, (envs,)),
            (ak.GOAL, runtime.goal, f8, (envs, 3)),
        ]
        if task is not None:
            g = task.scheduler.kernel_arrays()
            entries += [
                (ak.G_ISSUED, g["issued"], i8, (envs,)),
                (ak.G_T_GOAL, g["t_goal"], f8, (envs,)),
                (ak.G_REACHED, g["reached"], b1, (envs,)),
                (ak.G_AGE, g["age"], f8, (envs,)),
                (ak.G_DUE, g["due"], b1, (envs,)),
                (ak.G_CHECK, g["check"], b1, (envs,)),
                (ak.G_EE, g["ee"], f8, (envs, 3)),
                (ak.G_BEST, g["best_distance"], f8, (envs,)),
                (ak.G_DISTANCE, g["distance"], f8, (envs,)),
                (ak.G_HIT, g["hit"], b1, (envs,)),
            ]
        if motion:
            hook, hooks = motion_hook, len(rig.hooks)
            entries += [
                (ak.TEMP, backend.thermal.kernel_arrays()["winding_temperature"], f8, e),
                (ak.PEAK, hook.peak, f8, e),
                (ak.PREV_DQ, hook.dq, f8, e),
                (ak.PREV_ACC, hook.acc, f8, e),
                (ak.JERK_SUM, hook.jerk_sum, f8, e),
                (ak.JERK_TICKS, hook.jerk_ticks, i8, (envs,)),
                (ak.MAX_SPEED, hook.max_speed, f8, (n,)),
                (ak.H_COUNTS, rig.hook_cost.counts, i8, (hooks, BINS + 1)),
                (ak.H_MAX, rig.hook_cost.max_ns, i8, (hooks,)),
            ]
        sid, datas = backend.robot.ee_site_id, list(backend.datas)
        no_site = np.zeros(3)  # a robot without an end effector (read only with a box or goals)

        def site(d):
            return d.site_xpos[sid] if sid >= 0 else no_site

        for env in range(envs):
            views = backend.env_views(env)
            if views["data"] is not datas[env]:
                return None
            entries += [
                (ak.VIEWS + env, views["qpos"], f8, (n,)),
                (ak.VIEWS + envs + env, views["qvel"], f8, (n,)),
                (ak.VIEWS + 2 * envs + env, site(datas[env]), f8, (3,)),
            ]
        if not all(put(table, arrays, *entry) for entry in entries):
            return None
        flags = (ak.HAS_WORKSPACE if rig.violations.has_workspace else 0) | (
            ak.HAS_PAIRS if rig.violations.has_pairs else 0
        )
        flags |= (ak.HAS_GOALS if task is not None else 0) | (int(RUNNING) << ak.RUNNING_SHIFT)
        flags |= (ak.LEGGED if legged else 0) | (int(SAFE_STOP) << ak.SAFE_STOP_SHIFT)
        table[: ak.HOOK_STAGE + 1] = (envs, n, pairs, rows, flags, BIN_NS, BINS, 0)
        return cls(rig, table, arrays, datas, motion)

    def ready(self, runtime) -> bool:
        """Whether the call's table still holds ``runtime``'s arrays and its plant's envs (the
        same objects as when it was built)."""
        return (
            runtime is self.runtime
            and runtime.mode is self._mode
            and runtime.goal is self._goal
            and self.backend.datas == self._datas  # MjData compare by identity
        )

    def __call__(self, runtime, motion: bool) -> None:
        """One tick's monitors, goal task and, with ``motion``, motion figures (class doc)."""
        start = time.perf_counter_ns()
        s = self._scheduler
        if s is None:
            code = self._call(runtime.time, start, 1.0, True, 1.0, 0.1, runtime.ticks > 2, motion)
        else:
            code = self._call(
                runtime.time, start, s.period, s.fixed is None, s.success_time,
                s.success_radius, runtime.ticks > 2, motion,
            )  # fmt: skip
        if code or self._legged:
            self._follow_up(code, runtime, start)

    def _follow_up(self, code: int, runtime, start: int) -> None:
        """Python's part of a tick whose call returned ``code`` (``after_tick_kernel`` bits), in
        the monitors' and the task's order (a legged robot's: its estimation monitor, timed
        with the monitors, and its task)."""
        rig = self.rig
        legged = self._legged
        if code & ak.MONITOR_WORK or legged:
            t0 = time.perf_counter_ns()
            if code & (ak.COLLISION_CHECK | ak.VIOLATION_FLAGGED):
                rig.violations.count_flagged(
                    self._q, self._dq, self._tau,
                    bool(code & ak.COLLISION_CHECK), bool(code & ak.VIOLATION_FLAGGED),
                )  # fmt: skip
            if code & ak.INTERVENTIONS_MOVED:
                rig.interventions.count_moved()
            rig.interventions.count_down()  # every tick of a legged robot's (it comes here)
            truth = None
            if legged and rig.estimation is not None:
                truth = self.backend.true_base_state()
                rig.estimation.update(runtime, truth)
            screens = int(self._stamp[2]) - start  # the call's part of the monitors
            rig.monitor_cost.add(0, screens + time.perf_counter_ns() - t0)
            if legged and rig.task is not None:
                if truth is not None and self._task_truth:
                    rig.task(runtime, truth)
                else:
                    rig.task(runtime)
        if code & ak.GOAL_DUE:
            self._scheduler.issue_due(runtime)
        if code & ak.GOAL_HIT:
            self._scheduler.record_hits()
