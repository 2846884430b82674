"""A trot trajectory generator inside a quadruped's actor: the policy's output is added to it.

Policies Modulating Trajectory Generators (A. Iscen et al., CoRL 2018): an open-loop periodic
gait gives the legs their rhythm, and the learned network adds corrections (balance, speed,
turning) on top. Here the generator is a fixed function of two observation blocks the spec
already carries, so the exported ONNX graph holds it and nothing outside the policy changes:

- ``gait_phase`` (sin, cos of ``phi = 2 pi t / period``): legs FL and RR at ``phi``, FR and RL
  at ``phi + pi`` (a trot);
- ``velocity_command`` (vx m/s, yaw rate rad/s): the stride.

Per leg, with ``s, c`` the sine and cosine of its phase, joint offsets from the home pose (rad)::

    swing = max(0, s)                                   # the foot is in the air while s > 0
    stride = stride_per_speed * vx + yaw_stride * side * wz
    thigh = stride * c + thigh_lift * swing             # fore-aft swing, and the lift
    calf = calf_lift * swing                            # the knee folds to clear the floor

``side`` is -1 for the left legs, +1 for the right ones (a left turn lengthens the right
strides). The hip (abduction) joints stay at home. The offsets are returned in action units
(divided by the spec's action scale), for a position-mode spec whose action offset is the home
pose (:data:`sim2real.deploy.spec.policy_spec.LEGGED_ACTION_SCALE`).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

#: Legs in robot order (FL, FR, RL, RR): the phase sign of each (a trot's diagonal pairs) and its
#: side (left -1, right +1).
PHASE_SIGN = (1.0, -1.0, -1.0, 1.0)
SIDE = (-1.0, 1.0, -1.0, 1.0)
#: Keys of a generator's description (``MLPActor.architecture["gait"]``).
KEYS = (
    "phase_index",
    "command_index",
    "command_scale",
    "action_scale",
    "stride_per_speed",
    "yaw_stride",
    "thigh_lift",
    "calf_lift",
)


class TrotPrior(nn.Module):
    """The trot generator (module docstring), as a torch module without parameters.

    Args:
        phase_index: Index of the ``gait_phase`` block's sine in the observation.
        command_index: Index of the ``velocity_command`` block's vx in the observation.
        command_scale: The command block's 3 scales (the observation holds command / scale).
        action_scale: The spec's action scale, one per joint (12: 4 legs x hip, thigh, calf).
        stride_per_speed: Thigh swing amplitude per commanded m/s, rad s/m.
        yaw_stride: Thigh swing amplitude per commanded rad/s of yaw rate, rad s/rad.
        thigh_lift, calf_lift: Offsets at mid-swing, rad.

    Raises:
        ValueError: an action scale that is not 12 positive entries.
    """

    def __init__(
        self,
        phase_index: int,
        command_index: int,
        command_scale: list[float],
        action_scale: list[float],
        stride_per_speed: float,
        yaw_stride: float,
        thigh_lift: float,
        calf_lift: float,
    ):
        super().__init__()
        if len(action_scale) != 12 or min(action_scale) <= 0:
            raise ValueError(
                f"TrotPrior: action_scale needs 12 positive entries, got {action_scale}"
            )
        self.description = {
            "phase_index": int(phase_index),
            "command_index": int(command_index),
            "command_scale": [float(x) for x in command_scale],
            "action_scale": [float(x) for x in action_scale],
            "stride_per_speed": float(stride_per_speed),
            "yaw_stride": float(yaw_stride),
            "thigh_lift": float(thigh_lift),
            "calf_lift": float(calf_lift),
        }
        self.phase_index, self.command_index = int(phase_index), int(command_index)
        self.vx_scale, self.wz_scale = float(command_scale[0]), float(command_scale[2])
        self.stride_per_speed, self.yaw_stride = float(stride_per_speed), float(yaw_stride)
        self.thigh_lift, self.calf_lift = float(thigh_lift), float(calf_lift)
        # buffers (not saved: the description is): per-leg signs, per-joint 1 / action scale
        self.register_buffer("phase_sign", torch.tensor(PHASE_SIGN), persistent=False)
        self.register_buffer("side", torch.tensor(SIDE), persistent=False)
        inverse = 1.0 / torch.tensor(action_scale, dtype=torch.float32)
        self.register_buffer("inverse_scale", inverse, persistent=False)

    @classmethod
    def from_description(cls, d: Any, where: str = "gait") -> TrotPrior:
        """The generator of a checkpoint's ``architecture["gait"]``.

        Raises:
            ValueError: not a dict with exactly :data:`KEYS` (the message names ``where``).
        """
        if not isinstance(d, dict) or set(d) != set(KEYS):
            got = sorted(d) if isinstance(d, dict) else type(d).__name__
            raise ValueError(f"{where}: expected the keys {sorted(KEYS)}, got {got}")
        return cls(**d)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Offsets from home in action units, (batch, 12), for observations (batch, obs_dim)."""
        p, c = self.phase_index, self.command_index
        sin = obs[:, p : p + 1] * self.phase_sign  # (batch, 4)
        cos = obs[:, p + 1 : p + 2] * self.phase_sign
        vx = obs[:, c : c + 1] * self.vx_scale
        wz = obs[:, c + 2 : c + 3] * self.wz_scale
        swing = torch.relu(sin)
        stride = self.stride_per_speed * vx + self.yaw_stride * wz * self.side
        thigh = stride * cos + self.thigh_lift * swing
        calf = self.calf_lift * swing
        hip = torch.zeros_like(thigh)
        legs = torch.stack([hip, thigh, calf], dim=2)  # (batch, 4 legs, 3 joints)
        return legs.reshape(obs.shape[0], 12) * self.inverse_scale
