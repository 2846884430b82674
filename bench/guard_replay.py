"""The guard replayed on a policy's own loop under pushes: where the PD barrier would act, and
whether the own loop (no guard) then has that joint past its hard limit.

``python -m bench.guard_replay [--robots h1_2] [--user NAME=ROBOT_DIR,POLICY[,YAML,PT]]
[--domain NAME=RANGES] [--seeds 0-9] [--seconds 60] [--apply force] [--max-velocity V]``

Each seed runs the policy's own loop of :mod:`bench.push_reference` (unitree_rl_gym's, or its
spec fed the true state) under the same pushes. After each control tick a fresh
:class:`~sim2real.deploy.safety.guard.SafetyGuard` (position mode) filters the loop's next PD
target from the true state (joints, the base's tilt, a foot in contact where MuJoCo has a contact
of the foot's body with the floor, as the barrier's loaded rows read it); its target is not
applied, the own loop runs on. Each joint the barrier changes is judged at the end of the next
control period (the benchmark's own measure of a crossing): past its hard limit there (the change
was where the policy crosses) or not (conservative by this measure), and whether its foot was
loaded (with the foot's normal force). Printed: ticks, ticks with a change, ticks whose end
finds a joint past its hard limit, and per joint: changes, those followed by a crossing, those
on a loaded foot, those on a loaded foot and not followed, the median gap to the limit the
change protects (negative: past it) and speed toward it.
"""

from __future__ import annotations

import argparse
import collections

import mujoco
import numpy as np

from bench.push_loops import truth_loop, unitree_loop
from bench.push_reference import _entries, _load, push_ranges
from sim2real.stacks.loops.bare import past_hard_limit
from sim2real.stacks.loops.unitree_rl_gym import load_torchscript


def replay_seed(entry, seed: int, args) -> tuple[collections.Counter, list[dict]]:
    """(counts, changes) of the guard replayed on ``entry``'s own loop at push sequence ``seed``
    (module docstring); each change a dict: joint, gap (rad), speed (rad/s, toward the limit),
    loaded, normal (N), crossed."""
    import yaml

    from sim2real.deploy.core.attitude import projected_gravity
    from sim2real.deploy.core.state import RobotState
    from sim2real.deploy.safety.guard import SafetyGuard
    from sim2real.deploy.safety.pd_barrier import foot_chains

    robot, policy = _load(entry)
    pushes = push_ranges(entry, robot, args)
    command = [float(x) for x in args.command.split(",")]
    guard = SafetyGuard(robot, 1, "position")
    state = RobotState.legged(1, robot.n_joints, robot.n_feet)
    guard.reset(np.asarray(robot.home, dtype=float)[None].copy())
    chains = foot_chains(robot)
    m = robot.plant_model("torque")
    feet = [m.body(f).id for f in robot.config.base.feet]
    lo, up = robot.position_lower, robot.position_upper
    qo, vo = robot.qpos_offset, robot.qvel_offset
    counts: collections.Counter = collections.Counter()
    changes: list[dict] = []
    pending: list[dict] = []
    wrench = np.zeros(6)
    out = np.empty((1, robot.n_joints))

    def watch(t, d, target):
        q = d.qpos[qo:]
        past = (q > up) | (q < lo)
        for c in pending:
            c["crossed"] = bool(past[c["joint"]])
        pending.clear()
        counts["ticks"] += 1
        counts["past_ticks"] += past_hard_limit(robot, q)
        normal = np.zeros(len(feet))
        for k in range(d.ncon):
            bodies = (m.geom_bodyid[d.contact[k].geom1], m.geom_bodyid[d.contact[k].geom2])
            for f, body in enumerate(feet):
                if body in bodies and 0 in bodies:
                    mujoco.mj_contactForce(m, d, k, wrench)
                    normal[f] += wrench[0]
        state.q[0], state.dq[0] = q, d.qvel[vo:]
        state.base.projected_gravity[0] = projected_gravity(d.qpos[3:7])
        state.foot_contact[0] = normal > 0.0
        guard.filter(target[None], state, out=out)
        changed = np.flatnonzero(out[0] != target)
        counts["changed_ticks"] += bool(changed.size)
        for j in changed:
            upper = out[0, j] < target[j]
            on = [f for f in range(len(feet)) if chains[f, j] > 0.0]
            c = {
                "joint": int(j),
                "gap": float(up[j] - q[j] if upper else q[j] - lo[j]),
                "speed": float(d.qvel[vo + j] * (1.0 if upper else -1.0)),
                "loaded": bool(on and state.foot_contact[0, on[0]] > 0.0),
                "normal": float(normal[on[0]]) if on else 0.0,
                "crossed": False,
            }
            changes.append(c)
            pending.append(c)

    if entry.config is not None:
        cfg = yaml.safe_load(entry.config.read_text())
        net = load_torchscript(entry.torchscript)
        unitree_loop(robot, cfg, net, seed, args.seconds, pushes, command, watch=watch)
    else:
        truth_loop(robot, policy, seed, args.seconds, pushes, command, watch=watch)
    return counts, changes


def report(name: str, robot, counts: collections.Counter, changes: list[dict]) -> list[str]:
    """The printed lines of one policy (module docstring)."""
    n = max(counts["ticks"], 1)
    crossed = sum(c["crossed"] for c in changes)
    lines = [
        f"{name}: ticks {counts['ticks']}, with a change {counts['changed_ticks']} "
        f"({counts['changed_ticks'] / n:.2%}), ending past a hard limit {counts['past_ticks']} "
        f"({counts['past_ticks'] / n:.2%}); changes {len(changes)}, followed by a crossing "
        f"{crossed} ({crossed / max(len(changes), 1):.0%})",
        "| joint | changes | followed by a crossing | loaded | loaded, not followed | "
        "median gap (rad) | median speed toward (rad/s) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    joints = collections.defaultdict(list)
    for c in changes:
        joints[c["joint"]].append(c)
    for j, cs in sorted(joints.items(), key=lambda kv: -len(kv[1])):
        loaded = [c for c in cs if c["loaded"]]
        lines.append(
            f"| {robot.joint_names[j]} | {len(cs)} | {sum(c['crossed'] for c in cs)} | "
            f"{len(loaded)} | {sum(not c['crossed'] for c in loaded)} | "
            f"{np.median([c['gap'] for c in cs]):.3f} | "
            f"{np.median([c['speed'] for c in cs]):.2f} |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.guard_replay", description=__doc__)
    p.add_argument("--robots", default="h1_2", help="shipped policies (go2, h1, h1_2)")
    p.add_argument("--user", action="append", default=[], metavar="NAME=ROBOT,POLICY[,YAML,PT]")
    p.add_argument("--domain", action="append", default=[], metavar="NAME=RANGES_FILE")
    p.add_argument("--seeds", default="0-9", help="first-last push sequences")
    p.add_argument("--seconds", type=float, default=60.0, help="s walked per run")
    p.add_argument("--command", default="0.5,0,0", help="vx,vy,yaw rate (m/s, rad/s)")
    p.add_argument("--max-velocity", type=float, default=None, help="legged_gym's pushes, m/s")
    p.add_argument("--apply", choices=("force", "velocity_hidden_from_imu"), default=None)
    p.add_argument("--window", type=float, default=None, help="s, a force push's duration")
    a = p.parse_args(argv)
    a.no_pushes = False
    lo, _, hi = a.seeds.partition("-")
    for entry in _entries(a, p):
        counts: collections.Counter = collections.Counter()
        changes: list[dict] = []
        for seed in range(int(lo), int(hi or lo) + 1):
            c, ch = replay_seed(entry, seed, a)
            counts.update(c)
            changes += ch
        robot, _ = _load(entry)
        print(f"seeds {a.seeds}, {a.seconds:g} s each; pushes {push_ranges(entry, robot, a)}")
        print("\n".join(report(entry.name, robot, counts, changes)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
