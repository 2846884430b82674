"""unitree_rl_gym's own loop (unitreerobotics/unitree_rl_gym, ``deploy/deploy_mujoco/
deploy_mujoco.py``, read, not copied), the ``legged_gym`` stack's ``own_loop`` face: the
observation from the true MuJoCo state (base angular velocity, projected gravity, command, joint
positions and velocities, last action, the 0.8-s gait phase's sine and cosine, scaled as the
deploy config says), the TorchScript policy the repository publishes (``motion.pt``), the target
``action x action_scale + default_angles`` for ``tau = kp (target - q) - kd dq`` at every
physics step; no estimator, guard or sensor noise. The push benchmark runs it on a robot's MJCF
with torque actuators (``bench.push_loops.unitree_loop``).
"""

from __future__ import annotations

import warnings

import numpy as np

from sim2real.deploy.core.attitude import projected_gravity

#: s, the gait phase's period in unitree's deploy_mujoco.py (H1, H1-2, G1)
GAIT_PERIOD = 0.8


def unitree_observation(cfg: dict, qpos, qvel, last_action, t: float, command) -> np.ndarray:
    """deploy_mujoco.py's observation (3 + 3 + 3 + 3 n + 2,) float32 from the true state."""
    n = len(last_action)
    phase = (t % GAIT_PERIOD) / GAIT_PERIOD
    return np.concatenate(
        [
            qvel[3:6] * cfg["ang_vel_scale"],
            projected_gravity(qpos[3:7]),  # deploy_mujoco.py's get_gravity_orientation
            np.asarray(command) * np.array(cfg["cmd_scale"]),
            (qpos[7 : 7 + n] - np.array(cfg["default_angles"])) * cfg["dof_pos_scale"],
            qvel[6 : 6 + n] * cfg["dof_vel_scale"],
            last_action,
            [np.sin(2 * np.pi * phase), np.cos(2 * np.pi * phase)],
        ]
    ).astype(np.float32)


def load_torchscript(path):
    """unitree's published policy (TorchScript, eval mode, one thread), loaded afresh: an LSTM
    policy keeps its memory in the module (``hidden_state``), so each run loads its own."""
    import torch

    torch.set_num_threads(1)
    with warnings.catch_warnings():  # torch.jit.load is deprecated; unitree publishes TorchScript
        warnings.simplefilter("ignore", FutureWarning)
        return torch.jit.load(str(path)).eval()


def controller(cfg: dict, net, plant, command=None):
    """deploy_mujoco.py's control step for ``plant`` (its MuJoCo ``d``, ``write``, ``target``:
    a bare plant whose PD law runs at every physics step): ``act(t)`` builds the observation of
    the true state at ``t`` (s, the gait clock), runs ``net`` (the TorchScript policy, eval mode)
    and writes the next PD target (rad, (n,)), which it returns. ``command``: (vx, vy, yaw
    rate) m/s, m/s, rad/s; default the deploy config's ``cmd_init``."""
    import torch

    command = cfg["cmd_init"] if command is None else command
    default = np.array(cfg["default_angles"], float)
    action = np.zeros(len(default), dtype=np.float32)
    d = plant.d

    def act(t: float) -> np.ndarray:
        nonlocal action
        with torch.no_grad():
            obs = unitree_observation(cfg, d.qpos, d.qvel, action, t, command)
            action = net(torch.from_numpy(obs)[None]).numpy()[0].astype(np.float32)
        plant.write(action * cfg["action_scale"] + default)
        return plant.target

    return act
