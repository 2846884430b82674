"""The Go2's trot generator with a residual network that starts at zero: where training starts.

:func:`make_policy` builds go2's default legged spec
(:meth:`sim2real.deploy.spec.policy_spec.PolicySpec.for_robot`:
IMU and joint blocks, the velocity command, a gait clock of ``PERIOD``) and an
:class:`~sim2real.deploy.policy.mlp_checkpoint.MLPActor` whose ``gait`` is the trot generator of
:mod:`sim2real.deploy.policy.gait_prior` with the constants below and whose network's last layer is zero: the
policy is the generator alone until a residual is trained on top of it (PMTG, Iscen et al. 2018)
by :mod:`sim2real.policies.train_legged`, which ships ``policies/go2.pt``. The constants were chosen by a
sweep through the full runtime (``deploy-run --robot go2 --command 0.5,0,0 --duration 20``:
forward speed, falls, interventions). ``python -m sim2real.policies.gait --out FILE`` writes the untrained
policy, to try the runtime with the bare generator.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import torch

from sim2real.deploy.policy.mlp_checkpoint import MLPActor, save_checkpoint
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.robots import load_robot

#: The trot's period, s (a quarter of a second per step: the Go2's trot at walking speed).
PERIOD = 0.4
#: Thigh swing amplitude per commanded m/s, rad s/m; per commanded rad/s of yaw rate, rad s/rad.
STRIDE_PER_SPEED, YAW_STRIDE = 1.2, 0.3
#: Thigh and calf offsets at mid-swing, rad (the calf stays inside its soft limit at -2.6 rad).
THIGH_LIFT, CALF_LIFT = -0.96, -1.1
#: The residual network's hidden layers (legged_gym's actor is 512-256-128; smaller suffices for
#: corrections).
HIDDEN = (128, 64)


def make_policy(robot_name: str = "go2") -> tuple[MLPActor, PolicySpec]:
    """The actor and spec of the trot policy of ``robot_name`` (a 12-joint quadruped)."""
    robot = load_robot(robot_name)
    spec = PolicySpec.for_robot(robot)
    blocks = tuple(
        dataclasses.replace(b, period=PERIOD) if b.name == "gait_phase" else b
        for b in spec.observation_blocks
    )
    spec = dataclasses.replace(spec, observation_blocks=blocks)
    spec.validate()
    where = spec.block_slices()
    command = next(b for b in blocks if b.name == "velocity_command")
    gait = {
        "phase_index": where["gait_phase"].start,
        "command_index": where["velocity_command"].start,
        "command_scale": list(command.scale),
        "action_scale": list(spec.action.scale),
        "stride_per_speed": STRIDE_PER_SPEED,
        "yaw_stride": YAW_STRIDE,
        "thigh_lift": THIGH_LIFT,
        "calf_lift": CALF_LIFT,
    }
    torch.manual_seed(0)
    actor = MLPActor(spec.obs_dim, spec.act_dim, HIDDEN, "elu", gait=gait)
    with torch.no_grad():
        actor.net[-1].weight.zero_()
        actor.net[-1].bias.zero_()
    return actor, spec


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim2real.policies.gait", description=__doc__.split("\n")[0]
    )
    p.add_argument("--robot", default="go2")
    p.add_argument("--out", type=Path, default=Path("go2_gait.pt"))
    args = p.parse_args(argv)
    actor, spec = make_policy(args.robot)
    info = {
        "recipe": "sim2real.policies.gait: trot generator, residual network at zero (not trained)",
        "period_s": PERIOD,
    }
    save_checkpoint(args.out, actor, spec, info=info)
    print(f"wrote {args.out} (trot generator, residual at zero)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
