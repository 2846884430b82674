"""The one assembly of a run (:class:`Rig`): the runtime of a robot, a policy and a backend, the
monitors and the task every run has, and the after-tick hooks a run adds.

``deploy-run``, the soak's batch, the training environments (the reach env steps the runtime's stages
with :mod:`~sim2real.deploy.rig.learner_tick`), the push benchmark and the runtime's acceptance run
build their runs here, so a run is judged the same way
wherever it runs: violations of the true state (a simulated plant only), interventions of the guard
and the smoother, a legged robot's base estimate against the truth (simulation), and the task (goals
or velocity commands, :func:`sim2real.deploy.tasks.task.task_for`).
"""

from __future__ import annotations

import time

import numpy as np

from sim2real.deploy.core.backend import SimulatedPlant
from sim2real.deploy.core.latency import LatencyHistogram
from sim2real.deploy.core.modes import FAULTED, RUNNING
from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.kinds import robot_kind
from sim2real.deploy.monitors.estimation import EstimationMonitor
from sim2real.deploy.rig.after_tick import FusedAfterTick
from sim2real.deploy.rig.after_tick_kernel import motion_tick
from sim2real.deploy.rig.hooks import RunHook

_UNBUILT = object()  # a rig's fused call not built yet (or its hooks changed since)


class Rig:
    """A run of ``envs`` robots: the runtime, its monitors, its task and its hooks.

    Args:
        robot: The robot (with the policy's drive applied, :func:`sim2real.deploy.spec.drive.drive_robot`).
        policy: The :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy`.
        backend: The backend (a :class:`~sim2real.deploy.core.backend.SimulatedPlant` is judged on its
            true state).
        envs: Robots in the batch (the backend's).
        task: Keyword arguments of :func:`sim2real.deploy.tasks.task.task_for` (``period`` and ``rng``
            at least); ``interventions`` is the rig's own monitor. None: no task, the runtime's goal
            and velocity command stay as they are (an acceptance run, whose policy ignores them).
        runtime: Keyword arguments of :class:`sim2real.deploy.runtime.Runtime` (``clock``, ``injector``,
            ``telemetry``, ``overrun_rate_limit``, ...).
        start: Start the runtime before the monitors and the task are built (the soak's order);
            False: :meth:`start` starts it (``deploy-run``'s).
        hooks: After-tick hooks, called in order after the monitors and the task.
        truth: Judge a simulated plant on its true state (violations, the base estimate); False:
            no truth monitors (training, which rewards its own way).
        reset_task: Reset the task's every env once built (False: the caller's episodes do).

    Attributes:
        runtime: The :class:`sim2real.deploy.runtime.Runtime`.
        violations: :class:`~sim2real.deploy.monitors.violations.ViolationMonitor` (a simulated plant;
            else None).
        interventions: :class:`~sim2real.deploy.monitors.interventions.InterventionMonitor`.
        estimation: :class:`~sim2real.deploy.monitors.estimation.EstimationMonitor` (a simulated legged
            robot; else None).
        task: The :class:`~sim2real.deploy.tasks.task.Task` (None without one).
        monitor_cost: :class:`~sim2real.deploy.core.latency.LatencyHistogram` of the monitors' time per
            tick (ns, outside the runtime's tick).
        hook_cost: One histogram stage per hook, in :attr:`hooks` order.

    A simulated robot's monitors, goal task and first hook's motion figures
    (:class:`MotionHook`; a legged robot's estimation monitor and velocity task follow it in
    Python) run as one compiled call per tick
    (:class:`~sim2real.deploy.rig.after_tick.FusedAfterTick`, built when the run starts and again
    when the plant's envs change), with the same results and timings as the separate calls
    every other run makes.

    Raises:
        ValueError: as the runtime and the task refuse their arguments.
    """

    def __init__(
        self,
        robot,
        policy,
        backend,
        *,
        envs: int,
        task: dict | None = None,
        runtime: dict | None = None,
        start: bool = False,
        hooks=(),
        truth: bool = True,
        reset_task: bool = True,
    ):
        from sim2real.deploy.monitors.interventions import InterventionMonitor
        from sim2real.deploy.monitors.violations import ViolationMonitor
        from sim2real.deploy.runtime import Runtime
        from sim2real.deploy.tasks.task import task_for

        self.robot, self.policy, self.backend, self.envs = robot, policy, backend, envs
        self.kind = robot_kind(robot)
        self.simulated = isinstance(backend, SimulatedPlant)
        self.runtime = Runtime(robot, policy, backend, kind=self.kind, **(runtime or {}))
        watch = getattr(backend, "watch_modes", None)  # drives that hold a stand until RUNNING
        if watch is not None:
            watch(self.runtime.mode)
        self._started = start
        if start:
            self.runtime.start()
        judged = self.simulated and truth
        self.violations = ViolationMonitor(robot, envs) if judged else None
        self.interventions = InterventionMonitor(self.runtime.guard, self.runtime.smoother)
        # the base estimate against the truth, where the kind's tick stage estimates one
        has_base = "base_estimator" in self.runtime.base_tick.parts()
        self.estimation = EstimationMonitor(robot, envs) if judged and has_base else None
        if self.estimation is not None and getattr(backend, "grounds", None):  # terrain
            self.estimation.ground = backend.ground_height
        #: bool: the robot lies damped after a stop (its kind's tick stage: a legged robot)
        self.lies_down = self.runtime.base_tick.lying(self.runtime.mode) is not None
        if self.violations is not None and self.lies_down:
            # a legged robot's ticks lying damped after a stop: apart, as the violations'
            self.interventions.down = self.violations.kernel_arrays()["down"]
        self.task = None
        if task is not None:
            self.task = task_for(robot, envs, backend, interventions=self.interventions, **task)
        excuse = getattr(self.task, "reference_contacts", None)  # a clip's own self-contacts
        if excuse is not None and self.violations is not None:
            self.violations.excuse_contacts(excuse)
        watch = getattr(self.task, "watch_violations", None)  # a clip's plays count them
        if watch is not None and self.violations is not None:
            watch(self.violations)
        if reset_task and self.task is not None:
            self.task.reset(self.runtime, np.ones(envs, dtype=bool))
        self.hooks: list[RunHook] = []
        self.monitor_cost = LatencyHistogram()
        self.hook_cost = LatencyHistogram(0)
        self._fused = _UNBUILT  # the one compiled call of the after-tick work (see _fused_call)
        for hook in hooks:
            self.add(hook)

    def add(self, hook: RunHook) -> RunHook:
        """Append ``hook`` (called after the monitors, the task and the hooks before it)."""
        self.hooks.append(hook)
        self.hook_cost = LatencyHistogram(len(self.hooks))
        self._fused = _UNBUILT  # its table holds the histograms and the first hook
        return hook

    # ------------------------------------------------------------------ the run
    def start(self) -> None:
        """Start the runtime (unless built with ``start=True``) and every hook."""
        if not self._started:
            self.runtime.start()
            self.interventions.resync()  # start zeroes the smoother's counters
            self._started = True
        for hook in self.hooks:
            hook.start(self)
        self._fused_call(self.runtime)  # built (its kernel loaded) before the first tick

    def _fused_call(self, runtime) -> FusedAfterTick | None:
        """The one compiled call of the monitors, the task and the motion figures
        (:class:`~sim2real.deploy.rig.after_tick.FusedAfterTick`) when it fits this run and
        holds ``runtime``'s arrays (built again when they changed); None: the separate calls."""
        fused = self._fused
        if fused is None:
            return None
        if fused is not _UNBUILT and fused.ready(runtime):
            return fused
        if runtime is not self.runtime:
            return None
        first = self.hooks[0] if self.hooks else None
        motion = first if type(first) is MotionHook and first.rig is self else None
        fused = self._fused = FusedAfterTick.build(self, motion)
        return fused if fused is not None and fused.ready(runtime) else None

    def monitor(self, runtime) -> None:
        """The monitors and the task after a tick (timed into :attr:`monitor_cost`); what
        every run does first after each tick."""
        fused = self._fused_call(runtime)
        if fused is not None:
            fused(runtime, False)
            return
        self._monitor(runtime)

    def _monitor(self, runtime) -> None:
        """:meth:`monitor` as separate calls of the monitors and the task."""
        t0 = time.perf_counter_ns()
        if self.violations is not None:
            # a robot lying damped after a stop (the kind's): its ticks are counted apart
            down = runtime.base_tick.lying(runtime.mode)
            self.violations.update(self.backend, down=down)
        self.interventions.update()  # before the goals: a goal's last tick counts for it
        if self.estimation is not None:
            self.estimation.update(runtime, self.backend.true_base_state())
        self.monitor_cost.add(0, time.perf_counter_ns() - t0)
        if self.task is not None:
            self.task(runtime)

    def after_tick(self, runtime) -> bool:
        """:meth:`monitor`, then every hook in order (each timed); True when a hook ends the
        run. What :meth:`run` passes to ``Runtime.run(on_tick=...)``."""
        fused = self._fused_call(runtime)
        first = 0
        if fused is None:
            self._monitor(runtime)
        else:  # the first hook's motion figures in the same call (timed there)
            fused(runtime, fused.motion)
            first = 1 if fused.motion else 0
        stop = False
        clock = time.perf_counter_ns
        for i in range(first, len(self.hooks)):
            t0 = clock()
            stop |= bool(self.hooks[i].after_tick(runtime))
            self.hook_cost.add(i, clock() - t0)
        return stop

    def run(self, ticks: int) -> None:
        """Run ``ticks`` control ticks (fewer when a hook ends the run)."""
        self.runtime.run(ticks, on_tick=self.after_tick)

    def close(self) -> None:
        """Close every hook, the last added first."""
        for hook in reversed(self.hooks):
            hook.close()

    def discard(self) -> None:
        """A refused or failed run: every hook's :meth:`~sim2real.deploy.rig.hooks.RunHook.discard`
        (released, no partial output), the last added first; each is tried even if one
        before it raised.

        Raises:
            Exception: the first error a hook's discard raised, after every hook was tried.
        """
        error = None
        for hook in reversed(self.hooks):
            try:
                hook.discard()
            except Exception as exc:  # noqa: BLE001 - the others still release theirs
                error = error or exc
        if error is not None:
            raise error

    # ------------------------------------------------------------------ the report
    def report(self) -> dict:
        """The monitors', the task's and the hooks' report entries: ``goals``, ``locomotion``,
        ``missed_goals`` (absent without a task), ``violations`` (None without ground truth),
        ``estimation``, ``interventions``, ``monitor_cost_us``, ``hook_cost_us`` and each hook's own
        (:meth:`RunHook.contribute`). A fall of the true base the runtime did not see counts
        in ``locomotion.falls`` (``runtime_falls`` and ``true_falls`` apart)."""
        report = {} if self.task is None else dict(self.task.report(self.runtime))
        report["violations"] = self.violation_report()
        report["estimation"] = None if self.estimation is None else self.estimation.summary()
        loco = report.get("locomotion")
        if loco is not None and self.estimation is not None:
            # in simulation a fall is the truth's: one the runtime did not see counts too
            loco["runtime_falls"] = loco["falls"]
            loco["true_falls"] = self.true_falls()
            loco["falls"] = max(loco["falls"], loco["true_falls"])
        report["interventions"] = self.interventions.summary()
        report["monitor_cost_us"] = self.monitor_cost.summary()
        report["hook_cost_us"] = {
            hook.name: self.hook_cost.summary(i) for i, hook in enumerate(self.hooks)
        }
        for hook in self.hooks:
            hook.contribute(report)
        return report

    def true_falls(self) -> int:
        """Falls of the true base (a simulated legged robot; else 0)."""
        return 0 if self.estimation is None else int(self.estimation.true_falls.sum())

    def violation_report(self) -> dict | None:
        """The true state's violations (ticks by type, ``any``, ``while_down``: lying damped
        after a stop); None without ground truth (hardware). What the hard ones were:
        ``hard_limit_joints`` (and ``hard_limit_joints_while_down``), each joint ever past its
        hard limit with its ticks past and its deepest position past it (``{joint: {"ticks",
        "depth_rad"}}``, every env's), ``velocity_joints`` and ``effort_joints`` (``{joint:
        {"ticks", "excess"}}``, rad/s and N m above the limit at most), and
        ``self_collision_pairs``, the collision pairs that touched while up (``{"geom_a|geom_b":
        ticks}``, every env's)."""
        if self.violations is None:
            return None
        v = self.violations
        true, down = v.totals(), v.totals(down=True)
        pairs: dict[str, int] = {}
        for e in range(self.envs):
            for pair, ticks in v.pair_counts(e).items():
                pairs[pair] = pairs.get(pair, 0) + ticks
        return {
            "hard_limit_joints": v.hard_limit_depths(),
            "hard_limit_joints_while_down": v.hard_limit_depths(down=True),
            "velocity_joints": v.joint_excess("velocity"),
            "effort_joints": v.joint_excess("effort"),
            "self_collision_pairs": dict(sorted(pairs.items(), key=lambda kv: -kv[1])),
            "reference_contact_ticks": int(v.reference_ticks.sum()),
            "reference_contact_pairs": v.reference_pair_counts(),
            "source": "true state (simulation ground truth)",
            "ticks": self.violations.ticks * self.envs,
            "by_type": {k: v for k, v in true.items() if k != "any"},
            "any": true["any"],
            "while_down": down,  # lying damped after a stop: apart, and still a hard violation
        }


class MotionHook(RunHook):
    """``deploy-run``'s motion figures: peak winding temperatures (degC), the largest joint
    speed (rad/s) and the mean absolute jerk while RUNNING (rad/s^3, second differences of the
    joint velocities at the control rate); true velocities and temperatures in simulation, else
    the estimate's and the drives' reports."""

    name = "motion"

    def __init__(self, rig: Rig):
        n, envs = rig.robot.n_joints, rig.envs
        self.rig = rig
        self.peak = np.full((envs, n), -np.inf)
        self.max_speed = np.zeros(n)
        self.dq, self.acc, self.jerk_sum = (np.zeros((envs, n)) for _ in range(3))
        self.jerk_ticks = np.zeros(envs, dtype=np.int64)
        self.dt = rig.robot.control_period
        self._bound: tuple | None = None  # the arrays the kernel's call is bound to

    def after_tick(self, r) -> None:
        sim = self.rig.backend if self.rig.simulated else None
        temperature = sim.thermal.winding_temperature if sim else r.state.winding_temperature
        dq = sim.true_velocity() if sim else r.state.dq
        b = self._bound
        if b is None or temperature is not b[0] or dq is not b[1] or r.mode is not b[2]:
            self._bind(temperature, dq, r.mode)
        self._call(r.ticks > 2)  # the kernel motion_statistics, bound to the arrays above

    def start(self, rig: Rig) -> None:
        # the call compiled (or loaded from numba's cache) before the first tick, for arrays of
        # the types of the run's (float64 (envs, n), like the hook's own); bound at that tick
        self._bind(self.peak, self.peak.copy(), rig.runtime.mode)
        self._bound = None

    def _bind(self, temperature: np.ndarray, dq: np.ndarray, mode: np.ndarray) -> None:
        """Bind the kernel's call to these arrays and the hook's own."""
        self._bound = (temperature, dq, mode)
        self._call = bind(
            motion_tick, temperature, self.peak, dq, self.dq, self.acc, float(self.dt), mode,
            RUNNING, self.jerk_sum, self.jerk_ticks, self.max_speed, rest=(True,),
        )  # fmt: skip

    def contribute(self, report: dict) -> None:
        names = self.rig.robot.joint_names
        jerk = self.jerk_sum.sum(axis=0) / max(int(self.jerk_ticks.sum()), 1)
        report["peak_winding_temperature_c"] = dict(
            zip(names, self.peak.max(axis=0).tolist(), strict=True)
        )
        report["max_joint_speed_rad_s"] = dict(zip(names, self.max_speed.tolist(), strict=True))
        report["mean_abs_jerk_rad_s3"] = dict(zip(names, jerk.tolist(), strict=True))


class LatchedStopHook(RunHook):
    """On hardware, the run ends once every env is FAULTED (the fault is latched: nothing more
    will happen until an operator resets it)."""

    name = "latched_stop"

    def after_tick(self, r) -> bool:
        return bool((r.mode == FAULTED).all())
