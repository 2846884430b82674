"""A small rl_sar RoboMimic folder written the way rl_sar ships its phase-clocked G1 dance
(fan-ziqi/rl_sar e384912 ``policy/g1/robomimic/charleston``: ``config.yaml`` under the key
``g1/robomimic/charleston``, ``model_name`` a TorchScript module, ``policy/g1/base.yaml`` two
folders up). The module is written as rl_sar's ``dance_0605_aligned.pt`` is (its ``DanceWrapper``,
read with ``torch.jit.load(...).code``): it takes rl_sar's history of 4 frames of 94 entries
(``ang_vel, gravity_vec, dof_pos 29, dof_vel 29, actions 29, RoboMimic_Deploy/phase``, newest
first), lays them out as RoboMimic_Deploy's ``Dance.run`` observation of 380 for the 23 joints
RoboMimic drives (``dof23_index``), runs the inner network (380 -> 23) and scatters its actions
into 29 (the wrists' 0); saved by ``torch.jit.trace`` (its code's ``CONSTANTS`` and unrolled
frames say it was traced). The weights are made up and small; the layout and sizes are the
stacks'.
"""

from __future__ import annotations

from pathlib import Path

import torch
import yaml
from torch import nn

from tests.rl_sar_files import G1_JOINTS, write_g1_base

#: RoboMimic_Deploy's ``dof23_index`` (policy/dance/config/Dance.yaml): the G1 joints it drives.
DOF23 = list(range(19)) + [22, 23, 24, 25]
KEY = "g1/robomimic/charleston"
TERMS = ["ang_vel", "gravity_vec", "dof_pos", "dof_vel", "actions", "RoboMimic_Deploy/phase"]
FRAME, FRAMES = 94, 4


class DanceWrapper(nn.Module):
    """rl_sar's port of RoboMimic's dance network (module docstring): (B, 376) -> (B, 29)."""

    def __init__(self, seed: int = 0, gain: float = 1e-3):
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        self.model = nn.Sequential(nn.Linear(380, 16), nn.ELU(), nn.Linear(16, 23))
        with torch.no_grad():
            for p in self.model.parameters():
                p.copy_(gain * torch.randn(p.shape, generator=g))
        self.register_buffer("idx", torch.tensor(DOF23), persistent=False)

    def forward(self, obs_history: torch.Tensor) -> torch.Tensor:
        terms: list[list[torch.Tensor]] = [[], [], [], [], [], []]
        for k in range(FRAMES):  # rl_sar's frames, newest first
            f = obs_history[:, k * FRAME : (k + 1) * FRAME]
            terms[0].append(f[:, 64:93][:, self.idx])  # actions
            terms[1].append(f[:, 0:3])  # ang_vel
            terms[2].append(f[:, 6:35][:, self.idx])  # dof_pos
            terms[3].append(f[:, 35:64][:, self.idx])  # dof_vel
            terms[4].append(f[:, 3:6])  # gravity
            terms[5].append(f[:, 93:94])  # phase
        history = torch.cat([torch.cat(t, -1) for t in terms], -1)
        phase = torch.min(terms[5][0], torch.tensor(1.0))
        obs = torch.cat(
            [terms[0][0], terms[1][0], terms[2][0], terms[3][0], history, terms[4][0], phase], -1
        )
        out = torch.zeros(obs_history.shape[0], 29, dtype=torch.float32)
        out[:, self.idx] = self.model(obs)
        return out


def write_robomimic_folder(
    root: Path, key: str = KEY, extra: dict | None = None, gain: float = 1e-3
) -> Path:
    """rl_sar's ``policy/`` tree under ``root``: ``g1/base.yaml`` and the folder of ``key``
    (``config.yaml``, ``dance.pt``); ``extra``: keys laid over config.yaml's; ``gain``: the
    standard deviation of the made-up weights (:class:`DanceWrapper`). Returns the folder."""
    n = len(G1_JOINTS)
    robot = root / "policy" / "g1"
    folder = robot.joinpath(*key.split("/")[1:])
    folder.mkdir(parents=True, exist_ok=True)
    home = [-0.1, 0, 0, 0.3, -0.2, 0] * 2 + [0.0] * 17
    write_g1_base(robot, home)
    config = {
        "model_name": "dance.pt",
        "num_observations": FRAME,
        "observations": TERMS,
        "observations_history": [0, 1, 2, 3],
        "observations_history_priority": "time",
        "clip_obs": 100.0,
        "clip_actions_lower": [-100.0] * n,
        "clip_actions_upper": [100.0] * n,
        "rl_kp": [100.0] * 15 + [40.0] * 14,
        "rl_kd": [2.5] * 15 + [1.0] * 14,
        "num_of_dofs": n,
        "action_scale": [0.25] * n,
        "wheel_indices": [],
        "ang_vel_scale": 0.25,
        "dof_pos_scale": 1.0,
        "dof_vel_scale": 0.05,
        "default_dof_pos": home,
        "joint_mapping": list(range(n)),
        **(extra or {}),
    }
    (folder / "config.yaml").write_text(yaml.safe_dump({key: config}, sort_keys=False))
    module = torch.jit.trace(DanceWrapper(gain=gain).eval(), torch.zeros(1, FRAME * FRAMES))
    torch.jit.save(module, str(folder / "dance.pt"))
    return folder
