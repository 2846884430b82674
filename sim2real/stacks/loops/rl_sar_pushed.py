"""rl_sar's tracking loop under the soak's pushes (:func:`rl_sar_loop`): one play of an rl_sar
folder's clip as rl_sar's own MuJoCo loop plays it (:mod:`sim2real.stacks.loops.rl_sar_tracking`,
:mod:`sim2real.stacks.loops.rl_sar_motion`) on a bare plant (:mod:`sim2real.stacks.loops.bare`),
pushed by the soak's schedule. The tracking push benchmark (``bench/push_tracking.py``) and the
soak's own-loop reference of a dance (:mod:`sim2real.eval.soak.own_loop_limits`) run it: the
``rl_sar`` stack's ``tracking_loop`` face (:data:`TRACKING_LOOP`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim2real.deploy.backends.sim.disturbances import SimDisturbances
from sim2real.deploy.core.stacks import TrackingLoop
from sim2real.eval.world.pushes import DomainPushes
from sim2real.stacks.loops.bare import Run, bare_plant, judge_tick
from sim2real.stacks.loops.rl_sar_motion import RlSarMotion, rl_sar_params
from sim2real.stacks.loops.rl_sar_tracking import load_policy, observation
from sim2real.stacks.loops.walk import Walk

#: s the own loop holds the home pose before the clip (rl_sar's GetUp before its dance state; our
#: choice of length: the robot at rest on its feet)
SETTLE = 1.0


def rl_sar_loop(
    robot, folder, seed: int, seconds: float | None, pushes, watch=None, repeat: int = 1
) -> Run:
    """One play of rl_sar ``folder``'s clip in rl_sar's loop (module docstring) on ``robot`` (its
    joints named as base.yaml's ``joint_names``), under ``pushes`` (a
    :class:`~sim2real.eval.world.pushes.PushRanges`; None: none), at most ``seconds`` s of clip
    (None: all of it). ``watch(d, target)`` (optional) sees each clip tick's true state (the
    ``mujoco.MjData`` the policy read) and the PD target (robot order, rad) the policy gave from
    it, before the physics steps (the soak's own-loop reference,
    :mod:`sim2real.eval.soak.own_loop_limits`). ``repeat``: plays of the clip back to back, each
    aligned by rl_sar's ``Reset`` to the robot as the last one left it (``seconds`` then caps
    them all; ``Run.walked``: s of clip played in all).

    Raises:
        ValueError: a joint of base.yaml the robot lacks, or a control period not rl_sar's
            ``dt x decimation``.
    """
    import torch

    folder = Path(folder)
    base, params = rl_sar_params(folder)
    missing = [j for j in base["joint_names"] if j not in robot.joint_names]
    if missing:
        raise ValueError(f"{folder}: base.yaml joint_names: {missing} are no joints of the robot")
    period = float(params["dt"]) * int(params["decimation"])
    if abs(period - robot.control_period) > 1e-9:
        raise ValueError(
            f"{folder}: dt x decimation {period} s is not the robot's control period "
            f"{robot.control_period} s"
        )
    slot = np.array([robot.joint_names.index(j) for j in base["joint_names"]])  # slot -> ours
    ours = slot[np.asarray(params["joint_mapping"])]  # policy entry i -> our joint index
    kp, kd = np.empty(robot.n_joints), np.empty(robot.n_joints)
    kp[ours], kd[ours] = params["rl_kp"], params["rl_kd"]
    scale = np.asarray(params["action_scale"], dtype=float)
    default = np.asarray(params["default_dof_pos"], dtype=float)
    lo, hi = np.asarray(params["clip_actions_lower"]), np.asarray(params["clip_actions_upper"])
    plant = bare_plant(robot, (kp, kd, np.array(robot.home, dtype=float)))
    m, d, target, step = plant.m, plant.d, plant.target, plant.advance  # target: in place
    qo, vo = robot.qpos_offset, robot.qvel_offset

    for _ in range(round(SETTLE / period)):
        step()
    motion = RlSarMotion(folder / params["motion_file"], 1.0 / period)
    waist = [list(params["joint_mapping"]).index(s) for s in params["waist_joint_indices"]]
    motion.reset(d.qpos[3:7].copy(), d.qpos[qo:][ours][waist])
    net = load_policy(folder / params["model_name"])
    actions = np.zeros(len(ours), dtype=np.float32)
    clip = round(motion.duration / period)
    ticks = clip * max(1, int(repeat))
    if seconds is not None:
        ticks = min(ticks, round(seconds / period))
    walk, run = Walk(), Run()
    schedule = DomainPushes([seed], pushes, period) if pushes else None
    bare = SimDisturbances(robot, [m], [d])
    for k in range(ticks):
        if k and k % clip == 0:  # the clip again: Reset to where the last play left the robot
            motion.reset(d.qpos[3:7].copy(), d.qpos[qo:][ours][waist])
        motion.update((k % clip) * period)
        q, dq = d.qpos[qo:][ours], d.qvel[vo:][ours]
        obs = observation(params, motion, d.qpos[3:7], d.qvel[3:6], q, dq, actions)
        with torch.no_grad():
            out = net(torch.from_numpy(obs)[None]).numpy()[0]
        actions = np.clip(out, lo, hi).astype(np.float32)
        target[ours] = actions * scale + default
        if watch is not None:
            watch(d, target)
        step()
        if judge_tick(run, walk, robot, d, k + 1, period, schedule, bare):
            break
    run.walked *= period
    run.pushes = [t - period for t in schedule.times[0]] if schedule else []  # the frame's time
    return run


def rl_sar_folder(policy: str | Path) -> Path | None:
    """The rl_sar ``whole_body_tracking`` folder the ONNX ``policy`` sits in (``config.yaml``,
    its TorchScript ``policy.pt`` and ``base.yaml`` two levels up, as rl_sar lays
    ``policy/<robot>/whole_body_tracking/<name>``), or None."""
    folder = Path(policy).resolve().parent
    if folder.parent.name != "whole_body_tracking":
        return None
    if not (folder / "config.yaml").is_file() or not (folder / "policy.pt").is_file():
        return None
    return folder if (folder.parent.parent / "base.yaml").is_file() else None


#: The ``rl_sar`` stack's ``tracking_loop`` face.
TRACKING_LOOP = TrackingLoop(
    what="rl_sar whole_body_tracking (the TorchScript policy.pt on the true state, its "
    "rl_kp/rl_kd; no estimator, guard or noise)",
    folder=rl_sar_folder,
    play=rl_sar_loop,
)
