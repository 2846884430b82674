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
from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.rig import after_tick_kernel as ak

#: The plant's methods whose truth the call reads from its views (a plant overriding one of them
#: is not fused).
_TRUTH = ("true_position", "true_velocity", "joint_torque", "end_effector_position")
#: The site of a robot without an end effector (read only with a box or goals, never written).
_NO_SITE = np.zeros(3)


class FusedAfterTick:
    """One compiled call of a rig's monitors, goals and motion figures per tick.

    Build it with :meth:`build` (None when the rig's run does not fit). Per tick: :meth:`ready`,
    then the call (:meth:`__call__`).

    Attributes:
        motion: The rig's first hook is its :class:`~sim2real.deploy.rig.rig.MotionHook`, whose
            work (and timing, as the hook's) the call does with ``motion``.
    """

    def __init__(self, rig, table, datas: list, motion: bool):
        """(:meth:`build` builds it.)"""
        self.rig, self.runtime, self.backend = rig, rig.runtime, rig.backend
        self._datas = datas  # the MjData its views name (alive with the call)
        self._mode, self._goal = rig.runtime.mode, rig.runtime.goal
        self.motion = motion
        #: a legged robot: the estimation monitor and the task run in Python after the call
        self._legged = rig.lies_down
        from sim2real.deploy.tasks.velocity import VelocityTask

        #: the legged task takes the truth the estimation monitor read (one read a tick)
        self._task_truth = self._legged and type(rig.task) is VelocityTask
        goals = rig.task is not None and not self._legged
        self._scheduler = rig.task.scheduler if goals else None
        at = table.arrays
        self._q, self._dq, self._tau = at["q"], at["dq"], at["tau"]
        self._stamp = at["stamp"]  # the clock's scratch, the end of the monitors' screens
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
        plant = backend.kernel_arrays()
        v, iv = rig.violations.kernel_arrays(), rig.interventions.kernel_arrays()
        values = dict(
            has_workspace=rig.violations.has_workspace, has_pairs=rig.violations.has_pairs,
            has_goals=task is not None, lies_down=legged, running=int(RUNNING),
            safe_stop=int(SAFE_STOP), bin_ns=BIN_NS, bins=BINS, hook_stage=0,
            margin=rig.violations.screen_margin, dt=motion_hook.dt if motion else 0.0,
            q=plant["qpos"], dq=plant["qvel"], tau=plant["torque"],
            stamp=np.zeros(3, dtype=np.int64), v_ee=v["ee"], v_offset_q=v["offset_q"],
            v_offset_ee=v["offset_ee"], v_bound=v["bound"], v_checked_q=v["checked_q"],
            v_clearance=v["clearance"], v_weights=v["pair_weights"], v_tmp=v["tmp"],
            v_need=v["need"], v_down=v["down"], v_ticks=v["ticks"], i_guard=iv["guard"],
            i_prev_guard=iv["previous_guard"], i_stopping=iv["stopping"],
            i_clamps=iv["clamps"], i_prev_smoother=iv["previous_smoother"],
            i_ticks=iv["ticks"], m_counts=rig.monitor_cost.counts,
            m_max=rig.monitor_cost.max_ns, mode=runtime.mode, goal=runtime.goal,
        )  # fmt: skip
        sizes = {"envs": envs, "n": n, "columns": BINS + 1}
        bounds = rig.violations.pair_bound_arrays()  # the bounds' screen joins the call
        values["has_bounds"] = bounds is not None
        if bounds is not None:
            values |= dict(zip(ak.BOUNDS_FIELDS, bounds, strict=True))
        else:  # not read (has_bounds False)
            values |= ak.AFTER.placeholders(ak.BOUNDS_FIELDS, sizes)
        goals = ("issued", "t_goal", "reached", "age", "due", "check", "ee", "distance", "hit")
        if task is not None:
            g = task.scheduler.kernel_arrays()
            values |= {f"g_{k}": g[k] for k in goals} | {"g_best": g["best_distance"]}
        else:  # not read (has_goals False)
            values |= ak.AFTER.placeholders([*(f"g_{k}" for k in goals), "g_best"], sizes)
        motion_fields = ("temperature", "peak", "prev_dq", "prev_acc", "jerk_sum", "jerk_ticks")
        motion_fields += ("max_speed", "h_counts", "h_max")
        if motion:
            hook = motion_hook
            values |= dict(
                temperature=backend.thermal.kernel_arrays()["winding_temperature"],
                peak=hook.peak, prev_dq=hook.dq, prev_acc=hook.acc, jerk_sum=hook.jerk_sum,
                jerk_ticks=hook.jerk_ticks, max_speed=hook.max_speed,
                h_counts=rig.hook_cost.counts, h_max=rig.hook_cost.max_ns,
            )  # fmt: skip
        else:  # not read (the call's motion False)
            values |= ak.AFTER.placeholders(motion_fields, sizes)
        sid, datas = backend.robot.ee_site_id, list(backend.datas)
        views = np.zeros((3, envs), dtype=np.int64)  # each env's MjData arrays (ak.QPOS ...)
        for env in range(envs):
            ev = backend.env_views(env)
            if ev["data"] is not datas[env]:
                return None
            site = datas[env].site_xpos[sid] if sid >= 0 else _NO_SITE
            for row, a in ((ak.QPOS, ev["qpos"]), (ak.QVEL, ev["qvel"]), (ak.SITE, site)):
                length = n if row != ak.SITE else 3
                if not (a.dtype == np.float64 and a.shape == (length,) and a.flags.c_contiguous):
                    return None
                views[row, env] = a.ctypes.data
        values["views"] = views
        if motion and len(rig.hook_cost.max_ns) != len(rig.hooks):
            return None
        table = ak.AFTER.pack_or_none(sizes, **values)
        if table is None or len(rig.monitor_cost.max_ns) != 1 or len(v["bound"]) != 3 * n + 3:
            return None
        return cls(rig, table, datas, motion)

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
