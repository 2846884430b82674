"""A published humanoid policy under legged_gym's pushes: our runtime beside unitree's own loop.

``python -m bench.push_reference [--robot h1] [--seeds 0-49] [--max-velocity 1.5]``

legged_gym's push (``LeggedRobot._push_robots``, unitree_rl_gym's humanoid configs:
``push_interval_s = 5``, ``max_push_vel_xy = 1.5``) sets the floating base's horizontal velocity
to a random value every 5 s. Does a policy fall under it because of our runtime, or would it fall
in its own stack's loop too? Each seed's push sequence (:func:`sim2real.eval.world.pushes.push_velocity`,
the soak's ``[pushes]``) runs, walking at the config's ``cmd_init``, for ``seconds``, in:

- **unitree's loop** (:func:`unitree_loop`): the loop of unitree_rl_gym's
  ``deploy/deploy_mujoco/deploy_mujoco.py``, written here for our robot's MJCF with torque
  actuators (``robot.plant_model("torque")``): the observation from the true MuJoCo state (base
  angular velocity, projected gravity, command, joint positions and velocities, last action, the
  0.8-s gait phase's sine and cosine, scaled as the deploy config says), the TorchScript policy
  the repository publishes (``motion.pt``), ``tau = kp (target - q) - kd dq`` at every physics
  step; no estimator, guard or sensor noise.
- **our runtime** (:func:`runtime_loop`): :class:`sim2real.deploy.runtime.Runtime` over
  :class:`~sim2real.deploy.backends.sim.plant.SimBackend` (position mode, its default sensor noise) with
  the policy exported to ONNX, as ``deploy-run`` runs it.

A run ends at its first fall: the base below ``FALL_HEIGHT``, or (ours) the runtime leaving
RUNNING. Printed per loop: falls, pushes survived before the fatal one, falls per push applied;
and the paired comparison per seed (same fatal push, ours earlier, ours later) with a two-sided
sign test.
"""

from __future__ import annotations

import argparse
import warnings
from math import comb
from pathlib import Path

import mujoco
import numpy as np
import yaml

from sim2real.deploy.core.attitude import projected_gravity
from sim2real.eval.world.pushes import push_velocity

DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "unitree_rl_gym"
#: m, base height below which the robot has fallen (the H1 stands at 1.0 m, walks at 0.98)
FALL_HEIGHT = 0.6
#: s between pushes (legged_gym's ``push_interval_s`` in unitree_rl_gym's humanoid configs)
PUSH_INTERVAL = 5.0
#: s, the gait phase's period in unitree's deploy_mujoco.py (H1, H1-2, G1)
GAIT_PERIOD = 0.8


def unitree_observation(cfg: dict, qpos, qvel, last_action, t: float) -> np.ndarray:
    """deploy_mujoco.py's observation (3 + 3 + 3 + 3 n + 2,) float32 from the true state."""
    n = len(last_action)
    phase = (t % GAIT_PERIOD) / GAIT_PERIOD
    return np.concatenate(
        [
            qvel[3:6] * cfg["ang_vel_scale"],
            projected_gravity(qpos[3:7]),  # deploy_mujoco.py's get_gravity_orientation
            np.array(cfg["cmd_init"]) * np.array(cfg["cmd_scale"]),
            (qpos[7 : 7 + n] - np.array(cfg["default_angles"])) * cfg["dof_pos_scale"],
            qvel[6 : 6 + n] * cfg["dof_vel_scale"],
            last_action,
            [np.sin(2 * np.pi * phase), np.cos(2 * np.pi * phase)],
        ]
    ).astype(np.float32)


def load_torchscript(path: Path):
    """unitree's published policy (TorchScript, eval mode, one thread), loaded afresh: an LSTM
    policy keeps its memory in the module (``hidden_state``), so each run loads its own."""
    import torch

    torch.set_num_threads(1)
    with warnings.catch_warnings():  # torch.jit.load is deprecated; unitree publishes TorchScript
        warnings.simplefilter("ignore", FutureWarning)
        return torch.jit.load(str(path)).eval()


def unitree_loop(robot, cfg: dict, net, seed: int, seconds: float, vmax: float, path=None):
    """One run of unitree's loop (module docstring) with ``net`` (the TorchScript policy, eval
    mode); returns the fall time s, or None. ``path``: a list that receives ``(t, x, y)`` (s, m)
    of the base after each control tick."""
    import torch

    m = robot.plant_model("torque")
    d = mujoco.MjData(m)
    d.qpos[7:] = robot.home
    mujoco.mj_forward(m, d)
    kp, kd = np.array(cfg["kps"], float), np.array(cfg["kds"], float)
    default = np.array(cfg["default_angles"], float)
    action = np.zeros(len(default), dtype=np.float32)
    target, dec = default.copy(), int(cfg["control_decimation"])
    dt = m.opt.timestep * dec
    every, steps = round(PUSH_INTERVAL / dt), 0
    for tick in range(1, round(seconds / dt) + 1):
        for _ in range(dec):
            d.ctrl[:] = kp * (target - d.qpos[7:]) - kd * d.qvel[6:]
            mujoco.mj_step(m, d)
            steps += 1
        t = steps * m.opt.timestep
        with torch.no_grad():
            obs = unitree_observation(cfg, d.qpos, d.qvel, action, t)
            action = net(torch.from_numpy(obs)[None]).numpy()[0].astype(np.float32)
        target = action * cfg["action_scale"] + default
        if path is not None:
            path.append((t, float(d.qpos[0]), float(d.qpos[1])))
        if d.qpos[2] < FALL_HEIGHT or not np.isfinite(d.qpos).all():
            return t
        if vmax > 0 and tick % every == 0:  # vmax 0: no push (setting 0 would stop the base)
            d.qvel[:2] = push_velocity(seed, tick // every, vmax)
    return None


def runtime_loop(robot, cfg: dict, onnx: Path, seed: int, seconds: float, vmax: float):
    """One run of our runtime (module docstring); returns (fall time s or None, cause)."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import RUNNING, Runtime

    plant = SimBackend(robot, "position", envs=1, seed=0)
    rt = Runtime(robot, OnnxPolicy(onnx, robot), plant)
    rt.velocity_command[0] = cfg["cmd_init"]
    rt.start()
    every, running = round(PUSH_INTERVAL / rt.dt), False
    for k in range(round(seconds / rt.dt)):
        rt.tick()
        running |= bool(rt.mode[0] == RUNNING)
        left = running and rt.mode[0] != RUNNING
        if plant.datas[0].qpos[2] < FALL_HEIGHT or left:
            return rt.time, (rt.cause_names()[0] if left else "height")
        if k > 0 and k % every == 0 and rt.mode[0] == RUNNING:
            plant.set_base_velocity(0, push_velocity(seed, k // every, vmax))
    return None, None


def _s(t: float | None) -> str:
    return "-" if t is None else f"{t:.2f} s"


def survived(fell_at: float | None, seconds: float) -> int:
    """Pushes survived before the fall (pushes at 5, 10, ... s)."""
    end = seconds if fell_at is None else fell_at
    return int(end // PUSH_INTERVAL) - (0 if fell_at is None else 1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="h1", help="h1 or h1_2 (the unitree_rl_gym test data)")
    ap.add_argument("--seeds", default="0-49", help="first-last push sequences")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--max-velocity", type=float, default=1.5, help="m/s per axis")
    a = ap.parse_args(argv)
    from sim2real.robots import load_robot

    robot = load_robot(a.robot)
    folder = DATA / a.robot
    cfg = yaml.safe_load((folder / f"{a.robot}.yaml").read_text())
    lo, hi = (int(x) for x in a.seeds.split("-"))
    rows, run = [], (a.seconds, a.max_velocity)
    for seed in range(lo, hi + 1):
        ref = unitree_loop(robot, cfg, load_torchscript(folder / "motion.pt"), seed, *run)
        ours, cause = runtime_loop(robot, cfg, folder / f"{a.robot}.onnx", seed, *run)
        rows.append((seed, ref, ours, cause))
        print(
            f"seed {seed:3d}  fell at: unitree's loop {_s(ref)}, ours {_s(ours)} ({cause})",
            flush=True,
        )
    for name, col in (("unitree's loop", 1), ("our runtime", 2)):
        falls = sum(r[col] is not None for r in rows)
        saved = sum(survived(r[col], a.seconds) for r in rows)
        print(
            f"{name:15s} falls {falls}/{len(rows)}, pushes survived {saved}, "
            f"falls per push {falls / max(saved + falls, 1):.3f}"
        )
    ref = np.array([survived(r[1], a.seconds) for r in rows])
    ours = np.array([survived(r[2], a.seconds) for r in rows])
    n, k = int((ref != ours).sum()), int((ours < ref).sum())
    p = min(1.0, 2 * sum(comb(n, i) for i in range(min(k, n - k) + 1)) / 2**n) if n else 1.0
    print(
        f"paired: same fatal push {int((ref == ours).sum())}, ours earlier {k}, ours later "
        f"{n - k}; sign test p = {p:.3f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
