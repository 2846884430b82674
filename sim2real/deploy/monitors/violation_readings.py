"""Reading a violation monitor's counts (:class:`sim2real.deploy.monitors.violations.
ViolationMonitor`): per type, per joint, per collision pair, per env; the monitor's public
arrays, summed or of one env."""

from __future__ import annotations

import numpy as np


class ViolationReadings:
    """The readings of :class:`~sim2real.deploy.monitors.violations.ViolationMonitor` (a base
    class of it) from its public arrays: ``counts``, ``any``, ``down_counts``, ``down_any``,
    ``pair_ticks``, ``reference_pair_ticks``, ``pair_names``, the per-joint arrays and
    ``robot.joint_names``."""

    def reference_pair_counts(self, env: int | None = None) -> dict[str, int]:
        """Env ``env``'s (None: all envs') ticks per pair in the reference's own contacts,
        most first."""
        ticks = (
            self.reference_pair_ticks.sum(axis=0) if env is None else self.reference_pair_ticks[env]
        )
        order = np.argsort(-ticks, kind="stable")
        return {self.pair_names[k]: int(ticks[k]) for k in order if ticks[k] > 0}

    def pair_counts(self, env: int) -> dict[str, int]:
        """Env ``env``'s ticks per collision pair that ever touched (``"geom_a|geom_b"``),
        most first."""
        ticks = self.pair_ticks[env]
        order = np.argsort(-ticks, kind="stable")
        return {self.pair_names[k]: int(ticks[k]) for k in order if ticks[k] > 0}

    def hard_limit_joints(self, env: int) -> dict[str, int]:
        """Env ``env``'s ticks beyond a hard limit per joint that ever was (while up), most
        first."""
        ticks = self.hard_joint_ticks[env]
        order = np.argsort(-ticks, kind="stable")
        names = self.robot.joint_names
        return {names[k]: int(ticks[k]) for k in order if ticks[k] > 0}

    def joint_excess(self, kind: str) -> dict[str, dict]:
        """Every env's joints above their ``kind`` (``"velocity"`` or ``"effort"``) limit, most
        ticks first: ``{joint: {"ticks": int, "excess": float}}``, the ticks (summed) and how far
        above the limit at most (rad/s or N m; up or lying down)."""
        ticks, excess = {
            "velocity": (self.speed_joint_ticks, self.speed_joint_excess),
            "effort": (self.effort_joint_ticks, self.effort_joint_excess),
        }[kind]
        ticks, excess = ticks.sum(axis=0), excess.max(axis=0)
        order = np.argsort(-ticks, kind="stable")
        names = self.robot.joint_names
        return {
            names[k]: {"ticks": int(ticks[k]), "excess": float(excess[k])}
            for k in order
            if ticks[k] > 0
        }

    def hard_limit_depths(self, env: int | None = None, down: bool = False) -> dict[str, dict]:
        """Each joint that was ever beyond its hard limit (while up; with ``down``, while lying
        down after a stop), most ticks first: ``{joint: {"ticks": int, "depth_rad": float}}``,
        its ticks past and how far past it was at most (rad), of env ``env`` (None: the ticks
        summed and the deepest over every env)."""
        ticks = self.down_hard_joint_ticks if down else self.hard_joint_ticks
        depth = self.down_hard_joint_depth if down else self.hard_joint_depth
        ticks = ticks.sum(axis=0) if env is None else ticks[env]
        depth = depth.max(axis=0) if env is None else depth[env]
        order = np.argsort(-ticks, kind="stable")
        names = self.robot.joint_names
        return {
            names[k]: {"ticks": int(ticks[k]), "depth_rad": float(depth[k])}
            for k in order
            if ticks[k] > 0
        }

    # ------------------------------------------------------------------ reading
    def totals(self, down: bool = False) -> dict[str, int]:
        """Ticks per type, summed over envs (and ``any``: ticks with any violation); of the
        ticks the envs were up, or with ``down`` of those they lay damped after a stop."""
        counts, any_ = (self.down_counts, self.down_any) if down else (self.counts, self.any)
        out = {t: int(v.sum()) for t, v in counts.items()}
        out["any"] = int(any_.sum())
        return out

    def env_counts(self, env: int, down: bool = False) -> dict[str, int]:
        """Ticks per type of env ``env`` (and ``any``); with ``down``, of its ticks down."""
        counts, any_ = (self.down_counts, self.down_any) if down else (self.counts, self.any)
        out = {t: int(v[env]) for t, v in counts.items()}
        out["any"] = int(any_[env])
        return out
