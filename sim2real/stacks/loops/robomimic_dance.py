"""A bare MuJoCo loop that plays RoboMimic_Deploy's phase-clocked dance as its own runtime does.

``python -m sim2real.stacks.loops.robomimic_dance MODEL.onnx DANCE.yaml SCENE.xml [--timestep 0.003]
[--decimation 7] [--settle 0.2] [--save q.npz]``

``MODEL.onnx``, ``DANCE.yaml``: RoboMimic_Deploy's (ccrpRepo/RoboMimic_Deploy ffe3d40,
``policy/dance/model/dance_0605.onnx``, ``policy/dance/config/Dance.yaml``; rl_sar's charleston
module wraps the same network); ``SCENE.xml``: a G1 29-dof MJCF with a floor, joints and motors in
the SDK's order (unitree_mujoco's ``scene_29dof.xml``). Written from RoboMimic_Deploy (read, not
copied), independent of this toolkit's runtime: ``deploy_mujoco.py`` (physics at 0.003 s, the
policy every 7 steps, ``--timestep``/``--decimation`` change them; PD ``kp (target - q) - kd dq``
at every physics step on ``qpos[7:]``/``qvel[6:]``, truth, torques clipped by the ``ctrlrange``
only; angular velocity ``qvel[3:6]``, gravity ``get_gravity_orientation``) and ``Dance.py``
(the 23 joints of ``dof23_index``; each term's 4 frames newest first, the newest this tick's;
``action, ang_vel x 0.25, q - default, dq x 0.05``, the histories, ``gravity, min(phase, 1)``:
380; targets ``default + 0.25 action``, the wrists at default; ``phase = counter x 0.02 / T``
after the tick: the first reads 0, 0.02 s a tick whatever the period).

Start: the default pose at unitree's 0.793 m, held by the dance's gains ``--settle`` s, then
``Dance.enter`` (RoboMimic walks there first). Runs ``T / 0.02`` ticks and prints the share played
before a fall (as :mod:`.rl_sar_tracking`), the joints' error against the policy's targets
(rad RMS, 29 joints: each tick's angles after its physics against its target, as ``deploy-run``'s
``motion phase`` line), the base's travel and the ticks ending with two robot bodies in contact;
``--save`` writes each tick's joint angles, base position and phase.

:func:`play` runs the same ``Dance`` on an rl_sar RoboMimic folder (``policy/<robot>/robomimic/
<name>``: config.yaml, the module of ``model_name``, whose inner network ``.model`` is RoboMimic's)
on a robot's bare plant (:mod:`sim2real.stacks.loops.bare`): the ``robomimic`` stack's
``tracking_loop`` face (:data:`TRACKING_LOOP`), the reference a run's hard-limit and
self-collision ticks are judged against (:mod:`sim2real.eval.soak.own_loop_limits`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import mujoco
import numpy as np
import yaml

from sim2real.deploy.core.stacks import TrackingLoop

#: A fall (rl_sar_tracking's): pelvis below this height, m, or tilted past FALL_TILT, rad.
FALL_HEIGHT = 0.35
FALL_TILT = np.deg2rad(60.0)
#: unitree_mujoco's G1 pelvis height at its home pose, m (g1_29dof.xml's pelvis body pos).
START_HEIGHT = 0.793
#: s of motion per policy tick in Dance.run (``motion_time = counter_step * 0.02``).
PHASE_STEP = 0.02


def gravity_orientation(quat) -> np.ndarray:
    """RoboMimic's ``get_gravity_orientation`` of a ``w x y z`` quaternion."""
    w, x, y, z = quat
    return np.array([2 * (-z * x + w * y), -2 * (z * y + w * x), 1 - 2 * (w * w + z * z)])


class Dance:
    """``Dance`` of RoboMimic_Deploy (module docstring): ``cfg`` its Dance.yaml, ``net``
    ``(1, 380) float32 -> (1, 23)``."""

    def __init__(self, cfg: dict, net):
        self.net = net
        self.kps = np.asarray(cfg["kps"], np.float32)
        self.kds = np.asarray(cfg["kds"], np.float32)
        self.default = np.asarray(cfg["default_angles"], np.float32)
        self.idx = np.asarray(cfg["dof23_index"], np.int64)
        self.ang_vel_scale = float(cfg["ang_vel_scale"])
        self.dof_pos_scale = float(cfg["dof_pos_scale"])
        self.dof_vel_scale = float(cfg["dof_vel_scale"])
        self.action_scale = float(cfg["action_scale"])
        self.h = int(cfg["history_length"])
        self.motion_length = float(cfg["motion_length"])
        self.n_act = int(cfg["num_actions"])
        self.enter()

    def enter(self) -> None:
        h, k = self.h, self.n_act
        self.action = np.zeros(k, np.float32)
        self.phase, self.counter = 0.0, 0
        self.bufs = {
            "action": np.zeros(k * h, np.float32),
            "ang_vel": np.zeros(3 * h, np.float32),
            "dof_pos": np.zeros(k * h, np.float32),
            "dof_vel": np.zeros(k * h, np.float32),
            "gravity": np.zeros(3 * h, np.float32),
            "phase": np.zeros(h, np.float32),
        }

    def run(self, q, dq, ang_vel, gravity) -> np.ndarray:
        """One policy tick: returns the 29 joint targets, rad (SDK order)."""
        qj = (q[self.idx] - self.default[self.idx]) * self.dof_pos_scale
        dqj = dq[self.idx] * self.dof_vel_scale
        w = np.asarray(ang_vel) * self.ang_vel_scale
        phase = np.array([min(self.phase, 1.0)], np.float32)
        new = {
            "action": self.action, "ang_vel": w, "dof_pos": qj, "dof_vel": dqj,
            "gravity": gravity, "phase": phase,
        }  # fmt: skip
        for name, value in new.items():  # newest first
            buf = self.bufs[name]
            buf[:] = np.concatenate([value, buf[: -len(value)]]).astype(np.float32)
        b = self.bufs
        history = [b["action"], b["ang_vel"], b["dof_pos"], b["dof_vel"], b["gravity"], b["phase"]]
        obs = np.concatenate([self.action, w, qj, dqj, *history, gravity, phase])
        obs = obs.astype(np.float32)[None]
        self.action = np.asarray(self.net(obs), np.float32).reshape(-1)
        target = self.default.astype(float).copy()
        target[self.idx] = self.action * self.action_scale + self.default[self.idx]
        self.counter += 1
        self.phase = self.counter * PHASE_STEP / self.motion_length
        return target


def onnx_net(path):
    """RoboMimic's ``ort_session.run`` of its ONNX file, one thread."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = opts.inter_op_num_threads = 1
    session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    return lambda obs: session.run(None, {name: obs})[0]


def run(
    model, config, scene, timestep=0.003, decimation=7, settle=0.2, save=None, net=None
) -> dict:
    """Play the dance once (module docstring); returns the figures :func:`main` prints.
    ``net``: the network ``(1, 380) float32 -> (1, 23)`` in place of ``model``'s ONNX session
    (the same network inside rl_sar's module, ``torch.jit.load(pt).model``)."""
    cfg = yaml.safe_load(Path(config).read_text())
    dance = Dance(cfg, net if net is not None else onnx_net(model))
    m = mujoco.MjModel.from_xml_path(str(scene))
    m.opt.timestep = float(timestep)
    d = mujoco.MjData(m)
    n = len(dance.default)
    if m.nu != n or m.nq != 7 + n:
        raise ValueError(f"{scene}: expected a floating base and {n} motors, got nu {m.nu}")
    d.qpos[2], d.qpos[7:] = START_HEIGHT, dance.default
    mujoco.mj_forward(m, d)
    target = dance.default.astype(float)
    kp, kd = dance.kps.astype(float), dance.kds.astype(float)

    def physics(steps):
        for _ in range(steps):
            d.ctrl[:] = kp * (target - d.qpos[7:]) - kd * d.qvel[6:]
            mujoco.mj_step(m, d)

    physics(round(settle / timestep))
    dance.enter()
    start = d.qpos[:3].copy()
    ticks = int(round(dance.motion_length / PHASE_STEP))
    err, played, fell, touching = np.zeros(n), 0, False, 0
    body = m.geom_bodyid
    qs, base, phases = [], [], []
    for _ in range(ticks):
        phases.append(min(dance.phase, 1.0))
        target = dance.run(
            d.qpos[7:].copy(), d.qvel[6:].copy(), d.qvel[3:6].copy(),
            gravity_orientation(d.qpos[3:7]),
        )  # fmt: skip
        physics(decimation)
        err += (d.qpos[7:] - target) ** 2
        pairs = zip(body[d.contact.geom1[: d.ncon]], body[d.contact.geom2[: d.ncon]], strict=True)
        touching += any(a != 0 and b != 0 for a, b in pairs)  # two robot bodies (0: the world)
        played += 1
        qs.append(d.qpos[7:].copy())
        base.append(d.qpos[:3].copy())
        up = 1.0 - 2.0 * (d.qpos[4] ** 2 + d.qpos[5] ** 2)
        if d.qpos[2] < FALL_HEIGHT or np.arccos(np.clip(up, -1, 1)) > FALL_TILT:
            fell = True
            break
    if save is not None:
        np.savez(save, q=np.array(qs), base=np.array(base), phase=np.array(phases))
    return {
        "ticks": played,
        "motion_ticks": ticks,
        "share": played / ticks,
        "fell": fell,
        "joint_rms": float(np.sqrt(err.sum() / (n * max(played, 1)))),
        "travel_m": float(np.linalg.norm(d.qpos[:2] - start[:2])),
        "self_contact_ticks": int(touching),
        "control_period": timestep * decimation,
    }


#: RoboMimic_Deploy's ``Dance.yaml`` values rl_sar's config.yaml does not carry (ccrpRepo/
#: RoboMimic_Deploy ffe3d40 ``policy/dance/config/Dance.yaml``): the 23 joints its network drives
#: (SDK order; rl_sar's module scatters them into 29), its history and action sizes.
DANCE_YAML = {"dof23_index": list(range(19)) + [22, 23, 24, 25], "history_length": 4,
              "num_actions": 23}  # fmt: skip


def robomimic_folder(policy) -> Path | None:
    """The rl_sar RoboMimic folder (``policy/<robot>/robomimic/<name>``: config.yaml, the
    TorchScript module its ``model_name`` names, ``base.yaml`` two levels up) the policy file
    ``policy`` (its ONNX export) sits in, or None."""
    folder = Path(policy).resolve().parent
    if folder.parent.name != "robomimic" or not (folder.parent.parent / "base.yaml").is_file():
        return None
    try:
        cfg = next(iter(yaml.safe_load((folder / "config.yaml").read_text()).values()))
        return folder if (folder / cfg["model_name"]).is_file() else None
    except (OSError, yaml.YAMLError, AttributeError, KeyError, TypeError, StopIteration):
        return None


def folder_dance(folder) -> tuple[dict, list[str], object]:
    """(the ``Dance`` config, the joints in its SDK order, the network ``(1, 380) float32 ->
    (1, 23)``) of an rl_sar RoboMimic ``folder``: ``kps``/``kds`` its ``rl_kp``/``rl_kd``,
    ``default_angles`` its ``default_dof_pos``, its scales, the motion's length as rl_sar's
    reader gives it (config.yaml's ``motion_length``, else rl_sar's fsm's), :data:`DANCE_YAML`;
    the network the module's inner ``.model`` (RoboMimic's ``dance_0605``).

    Raises:
        ValueError: no motion length for the folder's key (the reader's message).
    """
    import torch

    from sim2real.deploy.spec.foreign.rl_sar import LENGTH_KEY, MOTION_LENGTHS
    from sim2real.stacks.loops.rl_sar_motion import rl_sar_params, robot_dir

    folder = Path(folder).resolve()
    base, cfg = rl_sar_params(folder)
    robot = robot_dir(folder)
    key = f"{robot.name}/{folder.relative_to(robot).as_posix()}"
    length = cfg.get(LENGTH_KEY, MOTION_LENGTHS.get(key))
    if length is None:
        raise ValueError(f"{folder / 'config.yaml'}: no '{LENGTH_KEY}' for {key}")
    scale = cfg["action_scale"]
    dance = {
        **DANCE_YAML, "kps": cfg["rl_kp"], "kds": cfg["rl_kd"],
        "default_angles": cfg["default_dof_pos"], "ang_vel_scale": cfg["ang_vel_scale"],
        "dof_pos_scale": cfg["dof_pos_scale"], "dof_vel_scale": cfg["dof_vel_scale"],
        "action_scale": scale[0] if isinstance(scale, list) else scale,
        "motion_length": float(length),
    }  # fmt: skip
    inner = torch.jit.load(str(folder / cfg["model_name"])).model

    def net(obs):
        with torch.no_grad():
            return inner(torch.from_numpy(obs)).numpy()

    joints = [base["joint_names"][i] for i in cfg["joint_mapping"]]
    return dance, joints, net


def play(robot, folder, seed: int, seconds: float | None, pushes, watch=None, repeat: int = 1):
    """One play of an rl_sar RoboMimic ``folder``'s dance by RoboMimic_Deploy's ``Dance`` (module
    docstring) on ``robot``'s bare plant (its ``plant_model("torque")``, the PD law of
    ``kps``/``kds`` at every physics step, the robot's own control period): the home pose held
    ``SETTLE`` s at the dance's default angles, then ``T / 0.02`` ticks, at most ``seconds`` s
    (None: all), under ``pushes`` (a :class:`~sim2real.eval.world.pushes.PushRanges`; None: none)
    seeded by ``seed``. ``watch(d, target)`` sees each tick's true state and the PD target
    (robot order, rad) before the physics steps. ``repeat``: plays back to back, the dance
    entered again (``Dance.enter``) where the last left the robot. Returns a
    :class:`~sim2real.stacks.loops.bare.Run` (``walked``: s of the dance played in all).

    Raises:
        ValueError: a joint of the folder the robot lacks, or no motion length.
    """
    from sim2real.deploy.backends.sim.disturbances import SimDisturbances
    from sim2real.eval.world.pushes import DomainPushes
    from sim2real.stacks.loops.bare import Run, bare_plant, judge_tick
    from sim2real.stacks.loops.walk import Walk

    cfg, joints, net = folder_dance(folder)
    missing = [j for j in joints if j not in robot.joint_names]
    if missing:
        raise ValueError(f"{folder}: joints {missing} are no joints of the robot")
    ours = np.array([robot.joint_names.index(j) for j in joints])  # SDK slot -> ours
    dance = Dance(cfg, net)
    kp, kd = np.zeros(robot.n_joints), np.zeros(robot.n_joints)
    kp[ours], kd[ours] = dance.kps, dance.kds
    target = np.array(robot.home, dtype=float)
    target[ours] = dance.default
    plant = bare_plant(robot, (kp, kd, target))
    d, period = plant.d, robot.control_period
    qo, vo = robot.qpos_offset, robot.qvel_offset
    for _ in range(round(SETTLE / period)):
        plant.advance()
    dance.enter()
    once = int(round(dance.motion_length / PHASE_STEP))
    ticks = once * max(1, int(repeat))
    if seconds is not None:
        ticks = min(ticks, round(seconds / period))
    walk, run = Walk(), Run()
    schedule = DomainPushes([seed], pushes, period) if pushes else None
    disturb = SimDisturbances(robot, [plant.m], [d])
    for k in range(ticks):
        if k and k % once == 0:
            dance.enter()
        out = dance.run(d.qpos[qo:][ours].copy(), d.qvel[vo:][ours].copy(), d.qvel[3:6].copy(),
                        gravity_orientation(d.qpos[3:7]))  # fmt: skip
        target[ours] = out
        plant.write(target)
        if watch is not None:
            watch(d, target)
        plant.advance()
        if judge_tick(run, walk, robot, d, k + 1, period, schedule, disturb):
            break
    run.walked *= period
    run.pushes = [t - period for t in schedule.times[0]] if schedule else []
    return run


#: s the dance's default angles are held before it starts in :func:`play`: :func:`run`'s
#: ``--settle`` default (held longer by its weak ankle gains, 20 N m/rad, the G1 tips forward:
#: 27 deg after 0.8 s on unitree_mujoco's g1_29dof.xml).
SETTLE = 0.2


#: The ``robomimic`` stack's ``tracking_loop`` face.
TRACKING_LOOP = TrackingLoop(
    what="RoboMimic_Deploy's Dance runtime (the module's inner network on the true state, "
    "rl_sar's rl_kp/rl_kd; no estimator, guard or noise)",
    folder=robomimic_folder,
    play=play,
)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim2real.stacks.loops.robomimic_dance", description=__doc__
    )
    p.add_argument("model", help="RoboMimic_Deploy's policy/dance/model/dance_0605.onnx")
    p.add_argument("config", help="RoboMimic_Deploy's policy/dance/config/Dance.yaml")
    p.add_argument("scene", help="a G1 29-dof MJCF (unitree_mujoco's g1_29dof.xml)")
    p.add_argument("--timestep", type=float, default=0.003, help="physics step, s")
    p.add_argument("--decimation", type=int, default=7, help="physics steps per policy tick")
    p.add_argument("--settle", type=float, default=0.2, help="s held at the default pose first")
    p.add_argument("--save", default=None, help="write each tick's joint angles (.npz)")
    a = p.parse_args(argv)
    r = run(a.model, a.config, a.scene, a.timestep, a.decimation, a.settle, a.save)
    print(
        f"played {r['ticks']}/{r['motion_ticks']} ticks ({100 * r['share']:.1f} %) at "
        f"{r['control_period'] * 1000:g} ms, falls {int(r['fell'])}; joint error against the "
        f"targets {r['joint_rms']:.4f} rad RMS (29 joints); base travel {r['travel_m']:.2f} m; "
        f"ticks with a self-contact {r['self_contact_ticks']}"
    )
    return 1 if r["fell"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
