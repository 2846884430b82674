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
"""

from __future__ import annotations

import argparse
from pathlib import Path

import mujoco
import numpy as np
import yaml

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
