"""A bare MuJoCo loop that runs a policy folder the way Unitree's C++ deployment runs it.

``python -m sim2real.stacks.loops.deploy_yaml_loop V0 SCENE.xml [--command 0.5,0,0] [--seconds 20]
[--timestep 0.002] [--armature A]``

``V0`` is a policy folder of unitree_rl_lab or unitree_rl_mjlab (``exported/policy.onnx``,
``params/deploy.yaml``); ``SCENE.xml`` an MJCF with a free-floating base whose hinge joints are
in the motor slots' order (unitree_mujoco's ``unitree_robots/g1/scene_29dof.xml``, or a robot
folder's MJCF). The reference for ``deploy-run`` on the same policy, written from their
``deploy/include/isaaclab`` code (read, not copied) and independent of this toolkit's reader:
deploy.yaml read with a safe loader that builds the ``builtins.slice`` tag; per observation term
a deque of ``history_length`` readings filled with the first at the start, each tick the reading
pushed, clipped then scaled, the oldest first, term after term; joints read at
``joint_ids_map[i]``; the velocity command clamped to ``commands.base_velocity.ranges``; the
target ``raw * scale + offset`` written to slot ``joint_ids_map[i]``; at every physics step the
torque ``stiffness * (target - q) - damping * dq`` (gains in the slots' order), clipped to the
scene's actuator ``ctrlrange`` (a scene without actuators: applied as joint forces, unclipped).
The true state is observed: base angular velocity in the base frame (the free joint's), gravity
projected into it. No estimator, guard, smoother or sensor noise. Prints the distance walked.
"""

from __future__ import annotations

import argparse
from collections import deque

import mujoco
import numpy as np
import onnxruntime as ort
import yaml


def load_deploy_yaml(path) -> dict:
    """deploy.yaml as their exporter writes it (``yaml.dump``: the slice tag)."""

    class Loader(yaml.SafeLoader):
        """yaml.SafeLoader and ``!!python/object/apply:builtins.slice``."""

    Loader.add_constructor(
        "tag:yaml.org,2002:python/object/apply:builtins.slice",
        lambda loader, node: slice(*loader.construct_sequence(node)),
    )
    with open(path) as f:
        return yaml.load(f, Loader=Loader)  # noqa: S506 - a SafeLoader subclass


def run(folder: str, scene: str, command, seconds: float, timestep: float, armature=None) -> dict:
    """One walk from the default pose; returns the path length, displacement and time walked
    (m, m, s) and whether the base fell below 0.4 m."""
    cfg = load_deploy_yaml(f"{folder}/params/deploy.yaml")
    session = ort.InferenceSession(
        f"{folder}/exported/policy.onnx", providers=["CPUExecutionProvider"]
    )
    ids = np.asarray(cfg["joint_ids_map"])
    kp, kd = np.asarray(cfg["stiffness"]), np.asarray(cfg["damping"])
    default = np.asarray(cfg["default_joint_pos"], np.float32)
    action = cfg["actions"]["JointPositionAction"]
    scale, offset = np.asarray(action["scale"]), np.asarray(action["offset"])
    ranges = cfg["commands"]["base_velocity"]["ranges"]
    lo = [ranges[k][0] for k in ("lin_vel_x", "lin_vel_y", "ang_vel_z")]
    hi = [ranges[k][1] for k in ("lin_vel_x", "lin_vel_y", "ang_vel_z")]
    command = np.clip(np.asarray(command, np.float32), lo, hi)
    m = mujoco.MjModel.from_xml_path(scene)
    m.opt.timestep = timestep
    if armature is not None:
        m.dof_armature[6:] = armature
    d = mujoco.MjData(m)
    target = np.zeros(len(ids))
    target[ids] = default
    d.qpos[7:] = target
    mujoco.mj_forward(m, d)
    last = np.zeros(len(ids), np.float32)

    def reading(name: str) -> np.ndarray:
        w, x, y, z = d.qpos[3:7]
        gravity_z_row = [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]
        return np.float32(
            {
                "base_ang_vel": d.qvel[3:6],
                "projected_gravity": -np.asarray(gravity_z_row),
                "velocity_commands": command,
                "joint_pos_rel": d.qpos[7:][ids] - default,
                "joint_vel_rel": d.qvel[6:][ids],
                "last_action": last,
            }[name]
        )

    terms = cfg["observations"]
    buffers = {k: deque([reading(k)] * t["history_length"]) for k, t in terms.items()}
    decimation = round(float(cfg["step_dt"]) / timestep)
    start, path, steps, fell = d.qpos[:2].copy(), 0.0, 0, False
    for _ in range(round(seconds / cfg["step_dt"])):
        steps += 1
        obs = []
        for name, term in terms.items():
            buffers[name].append(reading(name))
            buffers[name].popleft()
            for value in buffers[name]:
                value = value if term["clip"] is None else np.clip(value, *term["clip"])
                obs.append(value * np.float32(term["scale"]))
        raw = session.run(None, {"obs": np.concatenate(obs)[None].astype(np.float32)})[0][0]
        last = raw.astype(np.float32)
        target[ids] = raw * scale + offset
        before = d.qpos[:2].copy()
        for _ in range(decimation):
            tau = kp * (target - d.qpos[7:]) - kd * d.qvel[6:]
            if m.nu:
                d.ctrl[:] = np.clip(tau, *m.actuator_ctrlrange.T)
            else:
                d.qfrc_applied[6:] = tau
            mujoco.mj_step(m, d)
        path += float(np.linalg.norm(d.qpos[:2] - before))
        if d.qpos[2] < 0.4:
            fell = True
            break
    moved = d.qpos[:2] - start
    return {"seconds": steps * cfg["step_dt"], "path": path, "x": moved[0], "y": moved[1],
            "fell": fell}  # fmt: skip


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim2real.stacks.loops.deploy_yaml_loop", description=__doc__
    )
    p.add_argument("folder", help="policy folder: exported/policy.onnx, params/deploy.yaml")
    p.add_argument("scene", help="MJCF with the robot's joints in the motor slots' order")
    p.add_argument("--command", default="0.5,0,0", help="VX,VY,WZ (m/s, m/s, rad/s)")
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--timestep", type=float, default=0.002, help="physics step, s")
    p.add_argument("--armature", type=float, default=None, help="every joint's, kg m^2")
    args = p.parse_args(argv)
    command = [float(v) for v in args.command.split(",")]
    r = run(args.folder, args.scene, command, args.seconds, args.timestep, args.armature)
    print(
        f"{r['seconds']:.1f} s{' (fell)' if r['fell'] else ''}: path {r['path']:.2f} m "
        f"({r['path'] / r['seconds']:.3f} m/s); displaced {r['x']:+.2f} m x, {r['y']:+.2f} m y"
    )
    return 1 if r["fell"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
