"""Interventions: commands the safety guard or the command smoother changed, per check and tick.

An **intervention** is a command the guard or the smoother changed (a **violation**, the true
state past a limit: :mod:`sim2real.deploy.monitors.violations`).
Checks (``INTERVENTION_CHECKS``), from :attr:`sim2real.deploy.safety.guard.SafetyGuard.counts` and the
counters of :class:`sim2real.deploy.smoothing.CommandSmoother`:

- ``hard_limit``: the guard found the estimate (or the target, or the predicted position) beyond
  a hard limit; the runtime makes a safe stop.
- ``soft_limit``: position mode: a target clamped to the soft limit (an arm's; not a PD-target
  robot's). In velocity and torque mode the estimate in the soft band, a warning reported as
  ``soft_band_estimate`` that changes no command.
- ``pd_barrier``: a PD-target robot's position target changed because the joint's predicted
  motion under it would reach the hard limit or the soft band too fast to stop
  (:mod:`sim2real.deploy.safety.pd_barrier`).
- ``velocity``: a target clamped to the speed from which the joint still stops before its soft
  limit (torque mode: the torque governor replaced a torque).
- ``workspace``, ``self_collision``, ``effort``: a target rejected, the robot held (effort:
  gravity past the derated effort limit; torque mode: a torque clamped to it too).
- ``stopping_distance``: velocity mode: the smoother cut a target velocity so that the joint brakes
  before its soft limit (``stopping_distance_clamps_per_joint``).
- ``target_clamp``: the smoother clamped a target to the hard position limits, the soft velocity
  limit or the effort limit (``target_clamps_per_joint``).

A check counts a tick once per env when it changed the command of a joint of the env (for the
smoother: any joint's counter rose); ``any`` counts ticks on which a check did, ``safety`` those
of a check that is not the policy's style (:attr:`InterventionMonitor.by_design`). Fractions are
of the ticks observed in every mode (RAMP_IN and SAFE_STOP included) but a legged robot's ticks
lying damped after a stop (:attr:`InterventionMonitor.down`), counted apart (``while_down`` of
:meth:`InterventionMonitor.summary`) as the violation monitor counts them.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.kernels import any_true
from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.monitors import kernel as mk
from sim2real.deploy.monitors.monitor_state import MonitorState
from sim2real.deploy.safety.checks import CHECKS as GUARD_CHECKS

#: The smoother's checks (its counters of :meth:`InterventionMonitor.__init__`).
SMOOTHER_CHECKS = ("stopping_distance", "target_clamp")
#: The guard's checks (``hard_limit`` first, then the guard's count-row order), the smoother's.
INTERVENTION_CHECKS = (
    "hard_limit",
    *(c for c in GUARD_CHECKS if c != "hard_limit"),
    *SMOOTHER_CHECKS,
)
WARNINGS = ("soft_band_estimate",)


class InterventionMonitor(MonitorState):
    """Count the ticks on which the guard or the smoother changed a command, per env and check.

    Build it after :meth:`sim2real.deploy.runtime.Runtime.start` (which zeroes the smoother's counters) and
    call :meth:`update` once after every tick (the runtime's ``on_tick`` hook).

    Args:
        guard: The runtime's :class:`~sim2real.deploy.safety.guard.SafetyGuard`.
        smoother: The runtime's :class:`~sim2real.deploy.smoothing.CommandSmoother`.

    Attributes:
        counts: dict check (``INTERVENTION_CHECKS``) -> (envs,) int64, ticks on which that check
            changed a command of the env.
        any: (envs,) int64, ticks on which any check did.
        safety: (envs,) int64, ticks on which a check not in ``by_design`` did.
        by_design: The checks whose interventions are the policy's style, reported by the
            soak and not judged: none now. (A floating-base robot's PD targets past its joints'
            ranges were clamped by ``soft_limit`` and not judged; they pass now unless their
            predicted motion is unsafe, ``pd_barrier``, an intervention like any other.)
        ticks: int, ticks observed (calls of :meth:`update`).
        down: None (every env up: an arm, hardware), or a live (envs,) bool array, the envs
            lying damped after a stop this tick (the violation monitor's, which the rig fills
            first each tick); set by the rig.
        down_counts, down_any, down_safety, down_ticks: (envs,) int64 each (``down_counts`` per
            check): the part of ``counts``, ``any``, ``safety`` on ticks the env was down, and
            how many ticks it was (:meth:`count_down`). ``counts`` and the others hold every
            tick; :meth:`summary` gives the standing ticks' and the lying ticks' apart.

    Per tick it compares the counters with their values after the last tick (three comparisons
    without allocation); which check rose in which env is worked out only on ticks where some
    counter moved (the kernel :func:`sim2real.deploy.monitors.kernel.counters_moved`; its numpy reference
    is :class:`sim2real.deploy.monitors.reference.ReferenceInterventionMonitor`).
    """

    def __init__(self, guard, smoother):
        if GUARD_CHECKS[0] != "soft_limit":  # the rows below rely on the guard's order
            raise RuntimeError("sim2real.deploy.safety.checks.CHECKS must start with 'soft_limit'")
        self.mode = guard.mode
        self.envs = envs = guard.envs
        first = 0 if self.mode == "position" else 1  # the soft-limit row is a clamp only there
        self._guard = guard
        self._guard_names = GUARD_CHECKS[first:]
        self._guard_rows = guard.count_matrix[first:]  # a view: the live counters
        self._smoother = (
            ("stopping_distance", smoother.stopping_distance_clamps_per_joint),
            ("target_clamp", smoother.target_clamps_per_joint),
        )
        self.counts = {c: np.zeros(envs, dtype=np.int64) for c in INTERVENTION_CHECKS}
        self.any = np.zeros(envs, dtype=np.int64)
        self.safety = np.zeros(envs, dtype=np.int64)
        self.by_design = ()
        self._tick_count = np.zeros(1, dtype=np.int64)
        self.down: np.ndarray | None = None
        self.down_counts = {c: np.zeros(envs, dtype=np.int64) for c in INTERVENTION_CHECKS}
        self.down_any = np.zeros(envs, dtype=np.int64)
        self.down_safety = np.zeros(envs, dtype=np.int64)
        self.down_ticks = np.zeros(envs, dtype=np.int64)
        n = smoother.n_joints
        # the counters as they stood after the last tick
        self._prev_guard = np.zeros((len(self._guard_names), envs), dtype=np.int64)
        self._prev_smoother = np.zeros((len(self._smoother), envs, n), dtype=np.int64)
        self._warning_base = np.zeros(envs, dtype=np.int64)
        self._guard_changed = np.zeros(self._prev_guard.shape, dtype=bool)
        self._smoother_changed = np.zeros((envs, n), dtype=bool)
        self._rose = np.zeros(envs, dtype=bool)
        self._rose_safety = np.zeros(envs, dtype=bool)
        self._flags = np.zeros(envs, dtype=bool)
        self.resync()
        mk.warm_up()
        (_, stopping), (_, clamps) = self._smoother
        #: interventions_moved bound to the counters (the live arrays, never rebound)
        self._moved_call = bind(
            mk.interventions_moved, self._guard_rows, self._prev_guard, stopping, clamps,
            self._prev_smoother,
        )  # fmt: skip

    def resync(self) -> None:
        """Take the guard's and smoother's counters as they stand as the reference (after
        something reset them); nothing is counted for the difference."""
        np.copyto(self._prev_guard, self._guard_rows)
        for i, (_, counter) in enumerate(self._smoother):
            np.copyto(self._prev_smoother[i], counter)
        if self.mode != "position":
            np.copyto(self._warning_base, self._guard.counts["soft_limit"])

    # ------------------------------------------------------------------ per tick
    def update(self) -> None:
        """Count this tick's interventions (call once after each tick)."""
        self._tick_count[0] += 1
        if self._moved():  # some counter moved: which checks, which envs
            self.count_moved()
        self.count_down()

    def count_down(self) -> None:
        """Count this tick's envs lying down (:attr:`down`) in :attr:`down_ticks`; nothing
        without :attr:`down`. Once per tick, after :meth:`count_moved` (a compiled tick calls
        it after its own comparison)."""
        if self.down is not None and any_true(self.down):  # none down: nothing to add
            self.down_ticks += self.down

    def kernel_arrays(self) -> dict[str, np.ndarray]:
        """The live arrays of :meth:`update`'s comparison, by name, for a compiled call that runs
        it (:func:`sim2real.deploy.monitors.kernel.interventions_moved`; the arrays themselves,
        C-contiguous, never rebound), int64: ``guard`` (checks, envs), the guard's counters;
        ``previous_guard``, their values after the last tick; ``stopping`` and ``clamps`` (envs,
        n), the smoother's counters; ``previous_smoother`` (2, envs, n), theirs; ``ticks`` (1,),
        what :attr:`ticks` reads. Raises nothing."""
        (_, stopping), (_, clamps) = self._smoother
        return {
            "guard": self._guard_rows, "previous_guard": self._prev_guard,
            "stopping": stopping, "clamps": clamps, "previous_smoother": self._prev_smoother,
            "ticks": self._tick_count,
        }  # fmt: skip

    def _moved(self) -> bool:
        """Whether a guard or smoother counter moved since the last tick (the kernel
        :func:`sim2real.deploy.monitors.kernel.interventions_moved`)."""
        return self._moved_call()

    def count_moved(self) -> None:
        """Per check: which envs' counters rose this tick, after :meth:`update`'s comparison (or
        a compiled call's over :meth:`kernel_arrays`) found that some did."""
        flags, rose, safety, counts = self._flags, self._rose, self._rose_safety, self.counts
        down = self.down if self.down is not None and self.down.any() else None
        rose.fill(False)
        safety.fill(False)
        for i, name in enumerate(self._guard_names):
            np.greater(self._guard_rows[i], self._prev_guard[i], out=flags)
            counts[name] += flags
            if down is not None:
                self.down_counts[name] += flags & down
            rose |= flags
            if name not in self.by_design:
                safety |= flags
        np.copyto(self._prev_guard, self._guard_rows)
        for i, (name, counter) in enumerate(self._smoother):
            np.greater(counter, self._prev_smoother[i], out=self._smoother_changed)
            np.any(self._smoother_changed, axis=1, out=flags)
            counts[name] += flags
            if down is not None:
                self.down_counts[name] += flags & down
            rose |= flags
            safety |= flags
            np.copyto(self._prev_smoother[i], counter)
        self.any += rose
        self.safety += safety
        if down is not None:
            self.down_any += rose & down
            self.down_safety += safety & down

    # ------------------------------------------------------------------ reading
    def warnings(self) -> dict[str, np.ndarray]:
        """Warnings that changed no command, (envs,) int64 ticks each: ``soft_band_estimate``
        (velocity and torque mode: the estimate in the soft band; always 0 in position mode)."""
        if self.mode == "position":
            return {"soft_band_estimate": np.zeros(self.envs, dtype=np.int64)}
        return {"soft_band_estimate": self._guard.counts["soft_limit"] - self._warning_base}

    def summary(self, env: int | None = None) -> dict:
        """Counts and fractions of ticks, of env ``env`` or summed over every env: of the ticks
        the robot was up, and apart of those it lay down (:attr:`down`).

        Returns:
            ``{"ticks", "checks": {check: {"count", "fraction"}}, "any": {"count", "fraction"},
            "safety": {"count", "fraction"}, "by_design": [check, ...],
            "warnings": {name: {"count", "fraction"}}, "while_down": {"ticks", "checks", "any",
            "safety"}}``: ``ticks`` the ticks up (per env: ``ticks`` less its down ticks; over
            envs: summed), the counts of those ticks and their fractions of ``ticks``, 0.0
            before the first tick (``warnings``: of every tick, up or down); ``while_down`` the
            same of the ticks down (all zeros without :attr:`down`).
        """
        ticks_all = self.ticks if env is not None else self.ticks * self.envs

        def total(values: np.ndarray) -> int:
            return int(values[env]) if env is not None else int(values.sum())

        down_ticks = total(self.down_ticks)

        def entries(of_ticks: int, values: np.ndarray, down: np.ndarray | None) -> dict:
            n = total(values) - (0 if down is None else total(down))
            return {"count": n, "fraction": n / of_ticks if of_ticks else 0.0}

        up = ticks_all - down_ticks

        def lying(values: np.ndarray) -> dict:
            n = total(values)
            return {"count": n, "fraction": n / down_ticks if down_ticks else 0.0}

        return {
            "ticks": up,
            "checks": {c: entries(up, v, self.down_counts[c]) for c, v in self.counts.items()},
            "any": entries(up, self.any, self.down_any),
            "safety": entries(up, self.safety, self.down_safety),
            "by_design": list(self.by_design),
            "warnings": {k: entries(ticks_all, v, None) for k, v in self.warnings().items()},
            "while_down": {
                "ticks": down_ticks,
                "checks": {c: lying(v) for c, v in self.down_counts.items()},
                "any": lying(self.down_any),
                "safety": lying(self.down_safety),
            },
        }

    # ------------------------------------------------------------------ checkpoints
    _state_name = "interventions"

    def _arrays(self) -> dict[str, np.ndarray]:
        # counts/<check>, any, warning_base (envs,); prev/<counter> (envs,) or, for the
        # smoother's per-joint counters, (envs, n)
        out = {f"counts/{c}": v for c, v in self.counts.items()}
        out["any"] = self.any
        out["safety"] = self.safety
        out["warning_base"] = self._warning_base
        out.update({f"down/{c}": v for c, v in self.down_counts.items()})
        out["down_any"], out["down_safety"] = self.down_any, self.down_safety
        out["down_ticks"] = self.down_ticks
        for i, name in enumerate(self._guard_names):
            out[f"prev/{name}"] = self._prev_guard[i]
        for i, (name, _) in enumerate(self._smoother):
            out[f"prev/{name}"] = self._prev_smoother[i]
        return out
