"""Callbacks of the arm training recipe (:mod:`sim2real.policies.train`): the training signals per
episode (goals reached, violations, interventions) to TensorBoard with periodic saves
(:class:`ReachLogger`), and the annealing of PPO's exploration noise (:class:`NoiseAnneal`).
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback


class ReachLogger(BaseCallback):
    """Logs the training signals per finished episode to TensorBoard, and every
    ``save_every`` steps writes the policy so far to ``save`` (a callable taking the model).

    Violations (a hard limit crossed by the joint or the guard's estimate) and interventions
    (fraction of ticks on which the guard or the smoother changed the command) are logged apart.
    """

    def __init__(self, save=None, save_every: int = 0, points_every: int = 16):
        super().__init__()
        self.save, self.save_every, self._saved_at = save, save_every, 0
        self.points_every = points_every
        self.violations: list[int] = []
        self.success: list[float] = []
        self.interventions: list[float] = []
        self.history: list[dict] = []

    def _on_step(self) -> bool:
        for info, done in zip(self.locals["infos"], self.locals["dones"], strict=True):
            if done and "joint_limit_violations" in info:
                self.violations.append(info["joint_limit_violations"])
                self.success.append(info["is_success"])
                self.interventions.append(info.get("intervention_rate", 0.0))
        return True

    def _on_rollout_end(self) -> None:
        if len(self.success) >= self.points_every:  # one point per so many episodes
            rate, viol = float(np.mean(self.success)), float(np.mean(self.violations))
            interventions = float(np.mean(self.interventions))
            self.logger.record("reach/success_rate", rate)
            self.logger.record("reach/joint_limit_violations", viol)
            self.logger.record("reach/intervention_rate", interventions)
            self.history.append(
                {
                    "step": int(self.num_timesteps),
                    "success_rate": rate,
                    "joint_limit_violations": viol,
                    "intervention_rate": interventions,
                    "episodes": len(self.success),
                }
            )
            self.violations.clear()
            self.success.clear()
            self.interventions.clear()
        if self.save and self.save_every and self.num_timesteps - self._saved_at >= self.save_every:
            self._saved_at = self.num_timesteps
            self.save(self.model, self.history)


class NoiseAnneal(BaseCallback):
    """Anneals PPO's exploration noise during the last ``steps`` environment steps: every element
    of ``policy.log_std`` moves linearly from its learned value to ``final_log_std`` (and is no
    longer trained).

    Why: the runtime runs the policy's mean action. A policy trained with large exploration noise
    (gSDE with ``log_std_init = -2`` and 64 tanh features: an action noise of ~0.5) learns to let
    the noise carry it out of configurations where its mean action is ~0; run deterministically it
    stops there (docs/measurements.md gives the goals reached with and without the noise).
    Annealing makes the mean itself finish the motion.
    """

    def __init__(self, total_steps: int, steps: int, final_log_std: float):
        super().__init__()
        self.start = max(total_steps - steps, 0)
        self.span = max(total_steps - self.start, 1)
        self.final = final_log_std
        self._initial = None

    def _on_rollout_start(self) -> None:
        if self.num_timesteps < self.start or not hasattr(self.model.policy, "log_std"):
            return
        log_std = self.model.policy.log_std
        if self._initial is None:
            self._initial = log_std.detach().clone()
            log_std.requires_grad_(False)
        frac = min((self.num_timesteps - self.start) / self.span, 1.0)
        with torch.no_grad():
            log_std.copy_(self._initial + frac * (self.final - self._initial))
        if getattr(self.model, "use_sde", False):
            self.model.policy.reset_noise(self.model.env.num_envs)
        self.logger.record("reach/log_std_mean", float(log_std.mean()))

    def _on_step(self) -> bool:
        return True
