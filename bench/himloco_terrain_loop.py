"""HIMLoco's Go2 on terrain tiles in a bare MuJoCo loop that follows rl_sar's runtime: the policy's own
loop, the comparison for ``deploy-run --backend sim --terrain`` (sim2real/eval/world/terrain.py).

rl_sar (fan-ziqi/rl_sar e384912) runs ``policy/go2/himloco/himloco.pt`` on unitree_mujoco's
``go2.xml`` as its ``RL_Sim`` does (``src/rl_sar/src/rl_sim_mujoco.cpp``, ``library/core/rl_sdk``):
the observation of ``config.yaml``'s terms (commands x commands_scale, IMU gyro x ang_vel_scale,
gravity rotated into the IMU's frame, joint angles about default_dof_pos, joint speeds x
dof_vel_scale, the last raw action) in the policy's joint order (``q[i] =
sensordata[joint_mapping[i]]``), clipped to clip_obs, into a 6-frame history, newest first, zeros
before the first (``ObservationBuffer``, priority ``time``); TorchScript inference every ``dt x
decimation`` s; ``target = default_dof_pos + action_scale x action``; torques ``kp (target - q) -
kd dq`` with ``rl_kp``, ``rl_kd`` (40, 1). Ours: the PD torque at every physics step of ``dt``
(0.005 s, legged_gym's, for a deterministic loop; rl_sar's threads run it at dt beside MuJoCo's own
real-time stepping), the robot first brought from its ``home`` key to default_dof_pos over 1 s
with ``fixed_kp``/``fixed_kd`` (rl_sar's get-up), the command then held.

A crossing: the base reaches ``CROSSED_X`` m along x (the tile's rim, 4 m from its centre) without
tipping past 1 rad or its height above the ground under it falling under 0.4 x 0.32 m (the
project's fall judges). Usage::

    python -m bench.himloco_terrain_loop RL_SAR_DIR UNITREE_MUJOCO_DIR stairs_up:0.10 slope_up:15deg
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import mujoco
import numpy as np
import yaml

from sim2real.eval.world.terrain import apply_terrain, parse_terrain

CROSSED_X = 4.0
#: m the robot is put above its key pose on a tile (a foot sphere started inside the height
#: field is held by its prisms' walls)
DROP = 0.03
FALL_TILT, FALL_HEIGHT = 1.0, 0.4 * 0.32


def _config(rl_sar: Path) -> dict:
    base = yaml.safe_load((rl_sar / "policy/go2/base.yaml").read_text())["go2"]
    cfg = yaml.safe_load((rl_sar / "policy/go2/himloco/config.yaml").read_text())["go2/himloco"]
    return base | cfg


def _model(unitree_mujoco: Path, terrain, seed: int, dt: float):
    """go2.xml with a floor, the tile laid in; its missing visual meshes dropped."""
    spec = mujoco.MjSpec.from_file(str(unitree_mujoco / "unitree_robots/go2/go2.xml"))
    assets = unitree_mujoco / "unitree_robots/go2/assets"
    for mesh in list(spec.meshes):
        if not (assets / mesh.file).is_file() or (assets / mesh.file).stat().st_size == 0:
            for g in [g for g in spec.geoms if g.meshname == mesh.name]:
                spec.delete(g)
            spec.delete(mesh)
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
    spec.option.timestep = dt
    ground = None
    if terrain is not None:
        ground = apply_terrain(spec, terrain, np.random.default_rng([seed, 0]))
    return spec.compile(), ground


def run(rl_sar: Path, unitree_mujoco: Path, tile: str | None, seconds: float, vx: float, seed=0):
    """One run on ``tile`` (``--terrain`` syntax; None: the plane): a dict of whether it
    crossed, the time, x reached, whether and when it fell."""
    import torch

    cfg = _config(rl_sar)
    dt, decimation, n = float(cfg["dt"]), int(cfg["decimation"]), int(cfg["num_of_dofs"])
    terrain = None if tile in (None, "plane") else parse_terrain(tile)
    model, ground = _model(unitree_mujoco, terrain, seed, dt)
    data = mujoco.MjData(model)
    key = model.key("home").id
    mujoco.mj_resetDataKeyframe(model, data, key)
    if ground is not None:  # the key's base height above the ground at the start
        data.qpos[2] += float(ground.height_at(0.0, 0.0)) + DROP
    mujoco.mj_forward(model, data)
    policy = torch.jit.load(str(rl_sar / "policy/go2/himloco" / cfg["model_name"])).eval()
    mapping = np.asarray(cfg["joint_mapping"])
    default = np.asarray(cfg["default_dof_pos"], float)
    scale = np.asarray(cfg["action_scale"], float)
    kp, kd = np.asarray(cfg["rl_kp"], float), np.asarray(cfg["rl_kd"], float)
    fkp, fkd = np.asarray(cfg["fixed_kp"], float), np.asarray(cfg["fixed_kd"], float)
    history = np.zeros((max(cfg["observations_history"]) + 1, int(cfg["num_observations"])))
    action = np.zeros(n)
    quat_at = 3 * n

    def q_dq():
        s = data.sensordata
        return s[mapping], s[mapping + n]

    def torque(target, p, d):
        q, dq = q_dq()
        tau = p * (target - q) - d * dq
        data.ctrl[mapping] = tau

    start = q_dq()[0].copy()
    get_up = int(1.0 / dt)
    for k in range(get_up):  # rl_sar's get-up: the pose interpolated to default over 1 s
        torque(start + (default - start) * (k + 1) / get_up, fkp, fkd)
        mujoco.mj_step(model, data)
    command = np.array([vx, 0.0, 0.0])
    steps = int(seconds / dt)
    out = {"tile": tile, "crossed": False, "fell": False, "t_s": seconds}
    target = default.copy()
    for k in range(steps):
        if k % decimation == 0:
            q, dq = q_dq()
            s = data.sensordata
            w, x, y, z = s[quat_at : quat_at + 4]
            r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                          [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                          [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])  # fmt: skip
            gravity = r.T @ np.array([0.0, 0.0, -1.0])
            gyro = s[quat_at + 4 : quat_at + 7]
            obs = np.concatenate([
                command * np.asarray(cfg["commands_scale"]), gyro * cfg["ang_vel_scale"], gravity,
                (q - default) * cfg["dof_pos_scale"], dq * cfg["dof_vel_scale"], action,
            ])  # fmt: skip
            obs = np.clip(obs, -cfg["clip_obs"], cfg["clip_obs"])
            history[1:] = history[:-1].copy()
            history[0] = obs
            with torch.no_grad():
                x_in = torch.as_tensor(history.reshape(1, -1), dtype=torch.float32)
                action = policy(x_in).numpy()[0].astype(float)
            action = np.clip(action, cfg["clip_actions_lower"], cfg["clip_actions_upper"])
            target = default + scale * action
        torque(target, kp, kd)
        mujoco.mj_step(model, data)
        base = data.qpos[:3]
        up = 1 - 2 * (data.qpos[4] ** 2 + data.qpos[5] ** 2)  # the base z axis' world z
        floor = 0.0 if ground is None else float(ground.height_at(base[0], base[1]))
        if math.acos(max(-1.0, min(1.0, up))) > FALL_TILT or base[2] - floor < FALL_HEIGHT:
            out.update(fell=True, t_s=(k + 1) * dt)
            break
        if base[0] >= CROSSED_X:
            out.update(crossed=True, t_s=(k + 1) * dt)
            break
    out["x_m"] = float(data.qpos[0])
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m bench.himloco_terrain_loop")
    p.add_argument("rl_sar", type=Path, help="an rl_sar checkout (policy/go2/...)")
    p.add_argument("unitree_mujoco", type=Path, help="a unitree_mujoco checkout")
    p.add_argument("tiles", nargs="+", help="--terrain tiles (stairs_up:0.10, slope_up:15deg)")
    p.add_argument("--seconds", type=float, default=16.0)
    p.add_argument("--vx", type=float, default=0.5)
    p.add_argument("--seeds", type=int, default=1)
    args = p.parse_args(argv)
    for tile in args.tiles:
        runs = [
            run(args.rl_sar, args.unitree_mujoco, tile, args.seconds, args.vx, s)
            for s in range(args.seeds)
        ]
        crossed = sum(r["crossed"] for r in runs)
        each = [
            f"x {r['x_m']:.2f} m{' fell' if r['fell'] else ''} at {r['t_s']:.2f} s" for r in runs
        ]
        print(f"{tile}: crossed {crossed}/{len(runs)}; " + "; ".join(each))


if __name__ == "__main__":
    main()
