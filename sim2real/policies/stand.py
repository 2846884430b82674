"""The Go2's standing and lying-down policies (``go2_stand.pt`` and ``go2_lie.pt``, exported to
ONNX beside them). Not trained: linear policies written down, documented here.

**Stand** holds the home pose with extra joint damping.

``action = -DAMPING_GAIN * obs_dq``, where ``obs_dq = dq / 20`` is the ``joint_velocity`` block of
the walking policy's contract (``go2.pt``'s spec, reused unchanged, so both policies read the same
observation and hand over on one action mapping). The action maps to the PD target
``home + 0.25 * action`` (legged_gym's action scale about the default pose), so the target is
``home - 0.25 * 1.6 / 20 * dq = home - 0.02 s * dq``: with the drive's kp 20 N m/rad that adds
0.4 N m s/rad to its kd 0.5 (about 1.8 times the damping of the drive alone), and at rest the
target is the home pose, as the runtime's RAMP_IN commands it. The velocity command, the gait
clock and the last action are ignored: the robot stands still whatever the sticks say.

**Lie** outputs one constant action whose target is ``LIE_POSE``, the pose a damped Go2 settles
in on its belly (legs splayed, calves short of their stops); the operator hands over to it over
``lie_time`` (the hand-over's linear blend: a ramp from the pose it had to the lying one, the
bring-up's ramp run backwards), then damps. The folded pose of the emulator's start
(``LYING_POSES``: hips 0.05 rad) was tried first: the body then rests on its folded legs, and
once damped its weight pressed every calf 3 mrad past its hard limit (MuJoCo, 50 ticks).

Make them and export them (the export's parity checks and 1,000-tick closed-loop replay run as
for every policy)::

    python -m sim2real.policies.stand            # writes go2_stand.pt and go2_lie.pt
    policy-export sim2real/policies/go2_stand.pt # writes go2_stand.onnx beside it
    policy-export sim2real/policies/go2_lie.pt
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from sim2real.deploy.policy.mlp_checkpoint import MLPActor, read_checkpoint, save_checkpoint

#: Action per unit of the joint_velocity observation (dq / 20): 0.02 s of target lead per rad/s
#: (0.25 action scale); our choice, a damping the drive's kp 20 turns into 0.4 N m s/rad.
DAMPING_GAIN = 1.6
HERE = Path(__file__).parent
#: rad, the Go2's lying pose (FL, FR, RL, RR x hip, thigh, calf): where it settled 1 s after a
#: damped collapse from standing in MuJoCo (deploy-run --backend sim, the operator's damp at
#: 25 s of tests/data/operator/xbox_session.jsonl: hips +-0.50 / +-0.67, thighs 0.91 / 0.81,
#: calves -2.41 / -2.22), rounded; the body lies on its belly, no joint at a stop.
LIE_POSE = {
    "go2": (0.5, 0.9, -2.4, -0.5, 0.9, -2.4, 0.65, 0.82, -2.2, -0.65, 0.82, -2.2),
}


def make_stand(walk: Path = HERE / "go2.pt", out: Path = HERE / "go2_stand.pt") -> Path:
    """Write the standing policy's checkpoint to ``out`` with the contract of ``walk``.

    Raises:
        ValueError: ``walk``'s contract has no ``joint_velocity`` block.
    """
    ck = read_checkpoint(walk)
    spec = ck.spec
    where = spec.block_slices().get("joint_velocity")
    if where is None:
        raise ValueError(f"{walk}: spec: no joint_velocity block to damp")
    start = where.start
    actor = MLPActor(spec.obs_dim, spec.act_dim, hidden=(), activation="elu")
    with torch.no_grad():
        layer = actor.net[0]
        layer.weight.zero_()
        layer.bias.zero_()
        for j in range(spec.act_dim):
            layer.weight[j, start + j] = -DAMPING_GAIN
    info = {
        "algorithm": "none: a linear hold-home policy with joint damping, written down "
        "(sim2real/policies/stand.py)",
        "command": "python -m sim2real.policies.stand",
        "damping_gain": DAMPING_GAIN,
        "contract_from": walk.name,
    }
    return save_checkpoint(out, actor, spec, info=info)


def make_lie(walk: Path = HERE / "go2.pt", out: Path = HERE / "go2_lie.pt") -> Path:
    """Write the lying-down policy's checkpoint to ``out`` with the contract of ``walk``: a
    constant action, target = the robot's ``LIE_POSE``.

    Raises:
        ValueError: no lying pose for the contract's robot, or one its action clip cannot reach.
    """
    ck = read_checkpoint(walk)
    spec = ck.spec
    if spec.robot not in LIE_POSE:
        raise ValueError(f"{walk}: no lying pose for robot '{spec.robot}'")
    a = spec.action
    action = (np.asarray(LIE_POSE[spec.robot]) - np.asarray(a.offset)) / np.asarray(a.scale)
    if np.abs(action).max() > a.clip:
        raise ValueError(f"{walk}: the lying pose needs an action past the clip {a.clip}")
    actor = MLPActor(spec.obs_dim, spec.act_dim, hidden=(), activation="elu")
    with torch.no_grad():
        actor.net[0].weight.zero_()
        actor.net[0].bias.copy_(torch.as_tensor(action, dtype=torch.float32))
    info = {
        "algorithm": "none: a constant target, the folded lying pose (sim2real/policies/stand.py)",
        "command": "python -m sim2real.policies.stand",
        "contract_from": walk.name,
    }
    return save_checkpoint(out, actor, spec, info=info)


if __name__ == "__main__":
    print(make_stand())
    print(make_lie())
