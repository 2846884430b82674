"""A bare MuJoCo loop that plays an rl_sar ``whole_body_tracking`` folder as rl_sar's runtime does.

``python -m sim2real.stacks.loops.rl_sar_tracking FOLDER SCENE.xml [--start getup|clip] [--settle 1.0]
[--timestep 0.005] [--seconds S]``

``FOLDER`` is rl_sar's ``policy/g1/whole_body_tracking/<name>`` (``policy.pt`` TorchScript,
``config.yaml``, the clip CSV; ``base.yaml`` two levels up); ``SCENE.xml`` unitree_mujoco's
``unitree_robots/g1/scene_29dof.xml`` (its sensors: 29 joint positions, velocities, torques,
then the pelvis IMU's quaternion and gyro, the layout rl_sar's ``GetState`` indexes). The
reference for ``deploy-run`` on the same folder, written from rl_sar e384912 (read, not copied)
and independent of this toolkit's runtime: ``motion_loader.cpp`` (the clip, its forward-difference
velocities, the clock, the slerp, the torso from the waist joints, the yaw alignment),
``rl_sdk.cpp`` ``ComputeObservation``/``ComputeOutput``, ``rl_sim_mujoco.cpp``
``GetState``/``SetCommand``/``RunModel`` and ``fsm_g1.hpp`` (GetUp, then the dance state's
``Enter``: ``InitRL``, ``MotionLoader`` at ``1 / (dt * decimation)`` Hz, ``Reset`` with the IMU
quaternion and the waist angles). The motion functions live in :mod:`.rl_sar_motion`.

The start (``--start getup``, default): the robot at base.yaml's ``default_dof_pos`` dropped on
the floor from unitree's 0.793 m, held by rl_sar's GetUp gains (base.yaml ``fixed_kp``/``fixed_kd``)
for ``--settle`` s (held alone, that pose tips forward), then the dance state entered.
rl_sar's operator passes through its robomimic locomotion policy between GetUp and the dance; this
loop skips it (``Reset`` aligns the clip's heading to whatever the robot stands in). ``--start
clip``: the robot at the clip's first frame (joints, root orientation and height), held by the
policy's gains. The files: ``git -C RL_SAR archive HEAD policy/g1 | tar -x``, ``git -C
UNITREE_MUJOCO archive HEAD unitree_robots/g1 | tar -x``. Prints the share of the clip played,
falls (pelvis below ``FALL_HEIGHT`` or tilted past ``FALL_TILT``), joint-angle RMS error per group against the
clip at each tick, the anchor's orientation error (the angle of the observed relative quat), and
MPJPE: every body's position relative to the pelvis against the clip's (forward kinematics of the
clip's frame on the same MJCF, turned by the yaw alignment), mean over bodies and ticks.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import mujoco
import numpy as np

from sim2real.stacks.loops.rl_sar_motion import (
    RlSarMotion,
    quat_angle,
    quat_conj,
    quat_mul,
    rl_sar_params,
    torso_quat,
)

#: SDK motor slots of each body group (base.yaml ``joint_names``: legs 0-11, waist 12-14, arms).
GROUPS = {"legs": range(0, 12), "waist": range(12, 15), "arms": range(15, 29)}
#: A fall: the pelvis below this height, m, or tilted past FALL_TILT, rad.
FALL_HEIGHT = 0.35
FALL_TILT = np.deg2rad(60.0)


def load_policy(path):
    """rl_sar's ``policy.pt`` (TorchScript), eval mode, one thread."""
    import torch

    torch.set_num_threads(1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        return torch.jit.load(str(path)).eval()


def observation(params: dict, motion, quat, gyro, q, dq, actions) -> np.ndarray:
    """rl_sar's ``ComputeObservation`` for a whole_body_tracking config, (154,) float32.

    ``quat`` the IMU's w x y z, ``gyro`` (3,) rad/s body frame, ``q``/``dq`` (N,) in the policy's
    order (``motor_state.q[i]`` is slot ``joint_mapping[i]``), ``actions`` (N,) the last output.
    Terms in ``observations`` order; the result clipped to +-``clip_obs``.
    """
    mapping = np.asarray(params["joint_mapping"])
    default = np.asarray(params["default_dof_pos"], dtype=float)
    parts = []
    for name in params["observations"]:
        if name == "whole_body_tracking/motion_command":
            parts += [motion.joint_pos()[mapping], motion.joint_vel()[mapping]]
        elif name == "whole_body_tracking/motion_anchor_ori_b":
            waist = [q[list(mapping).index(i)] for i in params["waist_joint_indices"]]
            robot = torso_quat(np.asarray(quat, float), waist)
            ref = quat_mul(motion.init_quat, motion.anchor_quat())
            rel = quat_mul(quat_conj(robot), ref)
            w, x, y, z = rel
            r = np.array(
                [
                    [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                    [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                    [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
                ]
            )
            parts.append(r[:, :2].reshape(-1))  # MatrixFirstTwoColumns: R00 R01 R10 R11 R20 R21
        elif name == "ang_vel":
            parts.append(np.asarray(gyro, float) * float(params["ang_vel_scale"]))
        elif name == "dof_pos":
            rel = np.asarray(q, float) - default
            rel[list(params.get("wheel_indices") or [])] = 0.0
            parts.append(rel * float(params["dof_pos_scale"]))
        elif name == "dof_vel":
            parts.append(np.asarray(dq, float) * float(params["dof_vel_scale"]))
        elif name == "actions":
            parts.append(np.asarray(actions, float))
        else:
            raise ValueError(
                f"observation {name!r}: not a whole_body_tracking term this loop reads"
            )
    clip = float(params["clip_obs"])
    return np.clip(np.concatenate(parts), -clip, clip).astype(np.float32)


def _state(m: mujoco.MjModel, d: mujoco.MjData, mapping):
    """rl_sar's ``GetState``: (quat w x y z, gyro, q, dq) with q/dq in the policy's order."""
    n = len(mapping)
    s = d.sensordata
    return s[3 * n : 3 * n + 4].copy(), s[3 * n + 4 : 3 * n + 7].copy(), s[mapping], s[n:][mapping]


def _check_scene(m: mujoco.MjModel, n: int) -> None:
    """The sensor layout rl_sar's GetState indexes: N jointpos, N jointvel, N jointactuatorfrc
    (or torque), then a framequat and a gyro; N actuators on the hinge joints in order."""
    kinds = list(m.sensor_type[: 3 * n + 2])
    want = [mujoco.mjtSensor.mjSENS_JOINTPOS] * n + [mujoco.mjtSensor.mjSENS_JOINTVEL] * n
    if kinds[: 2 * n] != want or kinds[3 * n] != mujoco.mjtSensor.mjSENS_FRAMEQUAT:
        raise ValueError(
            "scene: not rl_sar's sensor layout (N jointpos, N jointvel, N, quat, gyro)"
        )
    if kinds[3 * n + 1] != mujoco.mjtSensor.mjSENS_GYRO or m.nu != n:
        raise ValueError(f"scene: expected a gyro after the quaternion and {n} actuators")
    if list(m.sensor_objid[:n]) != list(m.actuator_trnid[:n, 0]):
        raise ValueError("scene: joint sensors and actuators name different joints")


def run(
    folder, scene, start="getup", settle=0.2, timestep=None, seconds=None, fps=None, yaw=0.0
) -> dict:
    """Play the folder's clip once from ``start``; returns the figures (see :func:`main`).
    ``fps`` replaces rl_sar's clip rate ``1 / (dt * decimation)`` (a comparison, not rl_sar);
    ``yaw`` (rad) turns the robot about z before it is put down (the clip's heading follows it)."""
    folder = Path(folder)
    base, params = rl_sar_params(folder)
    n = int(params["num_of_dofs"])
    dt, decimation = float(params["dt"]), int(params["decimation"])
    mapping = np.asarray(params["joint_mapping"])
    m = mujoco.MjModel.from_xml_path(str(scene))
    _check_scene(m, n)
    m.opt.timestep = dt if timestep is None else timestep
    substeps = round(dt / m.opt.timestep)
    if substeps < 1 or abs(substeps * m.opt.timestep - dt) > 1e-9:
        raise ValueError(f"timestep: expected a divisor of dt {dt} s, got {m.opt.timestep}")
    d = mujoco.MjData(m)
    motion = RlSarMotion(folder / params["motion_file"], fps or 1.0 / (dt * decimation))
    slot_of = m.jnt_qposadr[m.actuator_trnid[:n, 0]]  # qpos address of motor slot j

    def pd_steps(target_slots, kp_slots, kd_slots, steps):
        for _ in range(steps):  # SetCommand at each control tick (dt), physics held over substeps
            q, dq = d.sensordata[:n], d.sensordata[n : 2 * n]
            d.ctrl[:] = kp_slots * (target_slots - q) - kd_slots * dq
            mujoco.mj_step(m, d, substeps)

    def policy_target(cfg, policy, obs):
        """Forward, clip the actions, ``ComputeOutput``'s target in motor slots."""
        with torch.no_grad():
            out = policy(torch.from_numpy(obs)[None]).numpy()[0]
        lo, hi = np.asarray(cfg["clip_actions_lower"]), np.asarray(cfg["clip_actions_upper"])
        actions = np.clip(out, lo, hi).astype(np.float32)
        target = np.empty(n)
        target[np.asarray(cfg["joint_mapping"])] = actions * np.asarray(
            cfg["action_scale"], float
        ) + np.asarray(cfg["default_dof_pos"], float)
        return actions, target

    def gains(cfg, kp="rl_kp", kd="rl_kd"):
        slots = np.asarray(cfg["joint_mapping"])
        kp_s, kd_s = np.empty(n), np.empty(n)
        kp_s[slots], kd_s[slots] = cfg[kp], cfg[kd]
        return kp_s, kd_s

    import torch

    # --- start: put the robot down and hold it (GetUp's pose and gains, or the clip's frame 0)
    if start == "getup":
        pose = np.empty(n)
        pose[np.asarray(base["joint_mapping"])] = base["default_dof_pos"]
        d.qpos[slot_of] = pose
        kp, kd = gains(base, "fixed_kp", "fixed_kd")
    elif start == "clip":
        pose = motion.joints[0]
        d.qpos[slot_of] = pose
        d.qpos[2] = motion.root_pos[0, 2]
        d.qpos[3:7] = motion.root_quat[0]
        kp, kd = gains(params)
    else:
        raise ValueError(f"start: expected 'getup' or 'clip', got {start!r}")
    d.qpos[3:7] = quat_mul([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)], d.qpos[3:7])
    mujoco.mj_forward(m, d)
    pd_steps(pose, kp, kd, round(settle / dt))
    # --- the dance state's Enter: InitRL (config.yaml), MotionLoader, Reset(imu quat, waist)
    policy = load_policy(folder / params["model_name"])
    quat, _, q, _ = _state(m, d, mapping)
    inverse = [list(mapping).index(i) for i in params["waist_joint_indices"]]
    motion.reset(quat, q[inverse])
    kp_s, kd_s = gains(params)
    actions = np.zeros(n, np.float32)  # InitObservations

    ticks = int(round(motion.duration / (dt * decimation)))
    if seconds is not None:
        ticks = min(ticks, int(round(seconds / (dt * decimation))))
    err_sq = np.zeros(n)
    anchor_deg, mpjpe, played, fell = [], [], 0, False
    ref = mujoco.MjData(m)  # the clip's pose, for body positions
    root = m.jnt_bodyid[0]  # the free joint's body (the pelvis)
    bodies = [b for b in range(1, m.nbody) if b != root]
    turn = np.empty(9)
    mujoco.mju_quat2Mat(turn, motion.init_quat)
    turn = turn.reshape(3, 3)
    for k in range(ticks):
        motion.update(min(k * dt * decimation, motion.duration))
        quat, gyro, q, dq = _state(m, d, mapping)
        ref_slots = motion.joint_pos()
        err_sq[mapping] += (q - ref_slots[mapping]) ** 2
        robot = torso_quat(quat, q[inverse])
        anchor_deg.append(
            np.rad2deg(quat_angle(quat_mul(quat_conj(robot), motion.aligned_anchor_quat())))
        )
        ref.qpos[3:7], ref.qpos[slot_of] = motion.root(), ref_slots
        mujoco.mj_kinematics(m, ref)
        mujoco.mj_kinematics(m, d)
        clip_rel = (ref.xpos[bodies] - ref.xpos[root]) @ turn.T
        mpjpe.append(np.linalg.norm(d.xpos[bodies] - d.xpos[root] - clip_rel, axis=1).mean())
        obs = observation(params, motion, quat, gyro, q, dq, actions)
        actions, target = policy_target(params, policy, obs)
        pd_steps(target, kp_s, kd_s, decimation)
        played = k + 1
        up = 1.0 - 2.0 * (d.qpos[4] ** 2 + d.qpos[5] ** 2)  # world z of the pelvis z axis
        if d.qpos[2] < FALL_HEIGHT or np.arccos(np.clip(up, -1, 1)) > FALL_TILT:
            fell = True
            break
    rms = {g: float(np.sqrt(err_sq[list(s)].sum() / (len(s) * played))) for g, s in GROUPS.items()}
    rms["all"] = float(np.sqrt(err_sq.sum() / (n * played)))
    return {
        "ticks": played,
        "clip_ticks": int(round(motion.duration / (dt * decimation))),
        "share": played / max(ticks, 1),
        "fell": fell,
        "rms": rms,
        "anchor_mean_deg": float(np.mean(anchor_deg)),
        "anchor_max_deg": float(np.max(anchor_deg)),
        "mpjpe_mm": 1000.0 * float(np.mean(mpjpe)),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim2real.stacks.loops.rl_sar_tracking", description=__doc__
    )
    p.add_argument("folder", help="rl_sar's policy/g1/whole_body_tracking/<name>")
    p.add_argument("scene", help="unitree_mujoco's unitree_robots/g1/scene_29dof.xml")
    p.add_argument("--start", choices=("getup", "clip"), default="getup")
    p.add_argument("--settle", type=float, default=0.2, help="s held before the dance")
    p.add_argument("--timestep", type=float, default=None, help="physics step, s (default: dt)")
    p.add_argument("--seconds", type=float, default=None, help="stop early, s of the clip")
    p.add_argument("--yaw", type=float, default=0.0, help="robot heading at start, rad")
    p.add_argument(
        "--fps", type=float, default=None, help="clip rate, Hz (rl_sar: the control rate)"
    )
    args = p.parse_args(argv)
    r = run(
        args.folder,
        args.scene,
        args.start,
        args.settle,
        args.timestep,
        args.seconds,
        args.fps,
        args.yaw,
    )
    rms = ", ".join(f"{g} {v:.4f}" for g, v in r["rms"].items())
    print(
        f"played {r['ticks']}/{r['clip_ticks']} ticks ({100 * r['share']:.1f} %), "
        f"falls {int(r['fell'])}; joint RMS rad: {rms}; anchor error deg: mean "
        f"{r['anchor_mean_deg']:.2f}, max {r['anchor_max_deg']:.2f}; MPJPE {r['mpjpe_mm']:.1f} mm"
    )
    return 1 if r["fell"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
