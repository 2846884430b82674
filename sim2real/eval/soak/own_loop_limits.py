"""An exhibition soak's hard-limit ticks and guard interventions judged against the policy's own
loop on the same clip (the guard-replay method, ``bench/guard_replay.py``) before the stack is
blamed for them: rl_sar's G1 dances hold their ankle rolls at, or a few mrad past, their hard
limits in their own loop, which has no guard.

:func:`own_loop_reference` plays the clip ``plays`` times in the policy's own loop (the
``tracking_loop`` face of the stack whose folder the policy sits in, :func:`own_tracking_loop`:
rl_sar's whole_body_tracking loop, RoboMimic_Deploy's dance) on the soak's robot under the soak's
pushes (its domain's ``[pushes]``, seeds ``seed`` .. ``seed + plays - 1``; without pushes the loop
is deterministic from its rest, so the plays go back to back, each from where the last left the
robot, as an exhibition plays its clip again; no faults, randomization or sensor noise: the true
state of the nominal robot), each play to the clip's end or its first fall, and counts per joint
the ticks past a hard limit, the ticks with a collision pair touching (``deploy-run``'s
judgement, :mod:`sim2real.deploy.cli.own_loop_check`) and, replaying a fresh
:class:`~sim2real.deploy.safety.guard.SafetyGuard` (position mode) on each tick's true state and
the policy's target (not applied), the ticks on which the guard would have changed it, per check.

The rule (:func:`judge_hard_limits`, :func:`judge_interventions`): a joint's own-loop rate (ticks
past its hard limit per second of clip) times the seconds of clip the session played is its
expected count; the session is allowed ``(1 + MARGIN) x expected + SIGMAS x sqrt(expected)``
ticks on that joint (three standard deviations of a Poisson count, so that a joint the own loop
crosses a few times is not blamed on the draw). Only the ticks past the allowance are the stack's;
``no_hard_violation`` fails on any of them, on any tick lying down after a stop, or on a
hard-limit safe stop. Every tick up counts (clips, transitions, rests: rl_sar's loop plays no rest,
so a rest gets no allowance). ``interventions`` passes at most ``max_intervention_rate`` of the
ticks, or at most ``(1 + MARGIN)`` times the share of the own loop's ticks the replayed guard
would have changed (the checks the session judges; a guide, not a bound: states our runtime did
not produce). Without an own loop here (no stack's tracking loop finds the ONNX's folder, or
``--motion`` another clip) a session is judged as before, and the report says why.
"""

from __future__ import annotations

import collections
import math
from pathlib import Path

import numpy as np

#: The share the session may exceed the own loop's rate by, per joint and for interventions:
#: a dance "within 10 % of its own loop" (our margin for every figure judged against it).
MARGIN = 0.10
#: Standard deviations of a Poisson count added to each joint's allowance (our choice: three).
SIGMAS = 3.0
#: Plays of the clip in the own loop (``soak-test --own-loop-plays``); our choice: 3, about a
#: minute of CPU per play of a 35-40 s G1 clip beside a soak of an hour.
OWN_LOOP_PLAYS = 3


def own_tracking_loop(policy: str | Path):
    """The policy's own tracking loop: the first registered stack (by rank) whose
    ``tracking_loop`` face (:class:`~sim2real.deploy.core.stacks.TrackingLoop`) finds its folder
    around ``policy`` (rl_sar's ``whole_body_tracking`` loop, RoboMimic_Deploy's dance on an
    rl_sar ``robomimic`` folder). The stacks sit on the top floor: the registry resolves the face
    at run time.

    Returns:
        ``(stack name, TrackingLoop, folder)``, or None when no stack's loop plays the policy.
    """
    from sim2real.deploy.core.stacks import with_face

    for stack, loop in with_face("tracking_loop"):
        folder = loop.folder(policy)
        if folder is not None:
            return stack.name, loop, folder
    return None


def play_reference(robot, policy: str | Path, plays: int, seed: int = 0, pushes=None) -> dict:
    """The own loop's figures on ``policy``'s motion (module docstring), ``plays`` plays on
    ``robot`` (its drive applied: the run's robot), seeds ``seed`` .. ``seed + plays - 1``,
    under ``pushes`` (a :class:`~sim2real.eval.world.pushes.PushRanges`); without pushes
    (None) the loop is deterministic from its rest: the ``plays`` plays go back to back, each
    from where the last left the robot (rl_sar's ``Reset``, RoboMimic's ``Dance.enter``).

    Returns:
        ``{"compared": False, "why": str}`` where no stack's loop plays the policy; else
        ``compared`` True, ``stack``, ``loop`` (what ran), ``folder``, ``plays``, ``falls``,
        ``clip_s`` (s of motion played, summed), ``ticks``, ``hard_limit_ticks`` (ticks with a
        joint past a hard limit), ``hard_limit_joints`` {joint: ticks}, most first,
        ``self_collision_ticks`` (ticks with a pair of ``safety.collision_pairs`` touching, the
        violation monitor's collision model), ``self_collision_pairs`` {pair: ticks},
        ``guard_checks`` {check: ticks the replayed guard's check changed the target},
        ``guard_patterns`` [[checks, ticks]], ``guard_ticks`` (ticks with any change),
        ``pushes`` (described, or None).
    """
    found = own_tracking_loop(policy)
    if found is None:
        return {
            "compared": False,
            "why": f"{policy}: no stack's own tracking loop plays it (an rl_sar "
            "whole_body_tracking or robomimic folder beside it: config.yaml, its module, "
            "base.yaml two levels up): no own loop to compare with",
        }
    stack, loop, folder = found
    replay = GuardReplay(robot)
    falls, clip_s = 0, 0.0
    # without pushes a play from the same rest is the same play: the plays go back to back
    # instead (the clip again where the last left the robot, as an exhibition repeats it)
    for k in range(plays if pushes is not None else 1):
        repeat = 1 if pushes is not None else plays
        run = loop.play(robot, folder, seed + k, None, pushes, replay, repeat)
        falls += run.fell_at is not None
        clip_s += run.walked
    joints = replay.joint_ticks
    order = np.argsort(-joints, kind="stable")
    pairs = replay.pair_ticks
    by_pair = np.argsort(-pairs, kind="stable")
    return {
        "compared": True,
        "stack": stack,
        "loop": loop.what,
        "folder": str(folder),
        "plays": plays,
        "falls": falls,
        "clip_s": clip_s,
        "ticks": replay.ticks,
        "hard_limit_ticks": replay.past_ticks,
        "hard_limit_joints": {robot.joint_names[j]: int(joints[j]) for j in order if joints[j] > 0},
        "self_collision_ticks": replay.collision_ticks,
        "self_collision_pairs": {
            replay.pair_names[k]: int(pairs[k]) for k in by_pair if pairs[k] > 0
        },
        "guard_checks": dict(replay.checks.most_common()),
        "guard_patterns": [[list(p), n] for p, n in replay.patterns.most_common()],
        "guard_ticks": sum(n for p, n in replay.patterns.items() if p),
        "pushes": None if pushes is None else pushes.describe(),
    }


def own_loop_reference(template, plays: int = OWN_LOOP_PLAYS) -> dict:
    """The own loop's figures (:func:`play_reference`) on the clip of ``template`` (a
    :class:`~sim2real.eval.soak.session.SessionConfig`) on the soak's robot under the soak's
    pushes (its domain's ``[pushes]``); ``{"compared": False, "why"}`` for 0 plays, another clip
    (``--motion``) or a policy no stack's loop plays."""
    if plays < 1:
        return {"compared": False, "why": "--own-loop-plays 0"}
    if template.motion is not None:
        return {"compared": False, "why": "--motion plays another clip than the policy's own loop"}
    if own_tracking_loop(template.policy) is None:
        return play_reference(None, template.policy, plays)
    from sim2real.deploy.kinds import robot_kind
    from sim2real.deploy.spec.drive import drive_robot
    from sim2real.eval.world.world_faces import WORLD_OF_KIND
    from sim2real.robots import load_robot

    robot = load_robot(template.robot)
    robot = drive_robot(robot, template.load_policy(robot).spec)[0]
    pushes = WORLD_OF_KIND.get(robot_kind(robot).name).domain_pushes(template.ranges)
    return play_reference(robot, template.policy, plays, template.seed, pushes)


class GuardReplay:
    """The own loop's watch (``watch(d, target)``): per tick, the joints past their hard limits
    in the true state ``d`` (a ``mujoco.MjData`` of ``robot``'s plant), the collision pairs
    touching there (the violation monitor's model: ``safety.collision_pairs`` of robot.toml,
    coal, :func:`~sim2real.deploy.safety.collision.collision_model`) and the checks a
    :class:`~sim2real.deploy.safety.guard.SafetyGuard` would have changed ``target`` (rad, robot
    order) by, from that state (joints, the base's tilt, a foot in contact where MuJoCo has a
    contact of its body with the floor: ``bench/guard_replay.py``'s reading)."""

    def __init__(self, robot):
        import mujoco

        from sim2real.deploy.core.state import RobotState
        from sim2real.deploy.safety.checks import CHECKS
        from sim2real.deploy.safety.collision import collision_model
        from sim2real.deploy.safety.guard import SafetyGuard

        self.robot, self.names = robot, CHECKS
        self.guard = SafetyGuard(robot, 1, "position")
        self.guard.reset(np.asarray(robot.home, dtype=float)[None].copy())
        self.state = RobotState.legged(1, robot.n_joints, robot.n_feet)
        self.m = robot.plant_model("torque")
        self.feet = [self.m.body(f).id for f in robot.config.base.feet]
        self.geom_body = self.m.geom_bodyid
        self._mujoco = mujoco
        self.lo, self.up = np.asarray(robot.position_lower), np.asarray(robot.position_upper)
        self.out = np.empty((1, robot.n_joints))
        self.ticks = self.past_ticks = 0
        self.joint_ticks = np.zeros(robot.n_joints, dtype=np.int64)
        self.checks: collections.Counter = collections.Counter()
        self.patterns: collections.Counter = collections.Counter()
        self.pin_model = robot.fixed_base_model
        self.pin_data = self.pin_model.createData()
        self.geom_model, self.geom_data = collision_model(robot)
        objects = self.geom_model.geometryObjects
        self.pair_names = [
            f"{objects[p.first].name}|{objects[p.second].name}"
            for p in self.geom_model.collisionPairs
        ]
        self.pair_ticks = np.zeros(len(self.pair_names), dtype=np.int64)
        self.collision_ticks = 0

    def __call__(self, d, target: np.ndarray) -> None:
        from sim2real.deploy.core.attitude import projected_gravity

        r = self.robot
        q = d.qpos[r.qpos_offset :]
        past = (q > self.up) | (q < self.lo)
        self.ticks += 1
        self.past_ticks += bool(past.any())
        self.joint_ticks += past
        self._collisions(q)
        contact = np.zeros(len(self.feet), dtype=bool)
        for k in range(d.ncon):
            bodies = (self.geom_body[d.contact[k].geom1], self.geom_body[d.contact[k].geom2])
            if 0 in bodies:
                for f, body in enumerate(self.feet):
                    contact[f] |= body in bodies
        s = self.state
        s.q[0], s.dq[0] = q, d.qvel[r.qvel_offset :]
        s.base.projected_gravity[0] = projected_gravity(d.qpos[3:7])
        s.foot_contact[0] = contact
        before = self.guard.count_matrix[:, 0].copy()
        self.guard.filter(np.asarray(target, dtype=float)[None], s, out=self.out)
        acted = tuple(
            self.names[i] for i in np.flatnonzero(self.guard.count_matrix[:, 0] != before)
        )
        self.checks.update(acted)
        self.patterns[acted] += 1

    def _collisions(self, q: np.ndarray) -> None:
        """Count the pairs touching at the joint angles ``q`` (rad, robot order)."""
        import pinocchio as pin

        if not self.pair_names:
            return
        args = (self.pin_model, self.pin_data, self.geom_model, self.geom_data, q)
        if not pin.computeCollisions(*args, False):
            return
        touching = [r.isCollision() for r in self.geom_data.collisionResults]
        self.pair_ticks += touching
        self.collision_ticks += 1


def allowance(rate_per_s: float, clip_s: float) -> float:
    """Ticks a joint may spend past its hard limit in ``clip_s`` s of clip when the own loop
    spends ``rate_per_s`` ticks per s there (module docstring's rule)."""
    expected = rate_per_s * clip_s
    return (1.0 + MARGIN) * expected + SIGMAS * math.sqrt(expected)


def session_clip_s(result: dict) -> float:
    """s of clip a session played: its plays' judged ticks times the control period (the
    session's simulated s over its ticks)."""
    dt = result["simulated_s"] / result["ticks"] if result.get("ticks") else 0.0
    return sum(int(c.get("ticks", 0)) for c in result["exhibition"]["clips"]) * dt


def judge_counts(ours: dict, own: dict, own_clip_s: float, clip_s: float) -> dict:
    """Each name's ticks (a joint's past its hard limit, or a kind's) judged by the module
    docstring's rule: ``ours`` {name: ticks} over ``clip_s`` s of motion against ``own`` {name:
    ticks} over the own loop's ``own_clip_s`` s. Returns {name: {ours, own, allowed, stack}}
    for every name in either, ``stack`` the ticks past the allowance (the soak's and
    ``deploy-run``'s one rule)."""
    out = {}
    for name in list(ours) + [n for n in own if n not in ours]:
        rate = own.get(name, 0) / own_clip_s if own_clip_s > 0 else 0.0
        allowed = allowance(rate, clip_s)
        n = int(ours.get(name, 0))
        out[name] = {
            "ours": n,
            "own": int(own.get(name, 0)),
            "allowed": round(allowed, 1),
            "stack": max(0, math.ceil(n - allowed)),
        }
    return out


#: The kinds of hard violation a tracking run's ticks are judged against its own loop on, and how
#: (:func:`judge_run`): a joint's hard limit per joint (as the soak's), self-collision as the
#: ticks with any pair touching.
JUDGED_KINDS = ("hard_limit", "self_collision")


def judge_run(violations: dict, own: dict, clip_s: float) -> dict:
    """``deploy-run``'s hard-limit and self-collision ticks (its report's ``violations``: the
    true state while up, every env) over ``clip_s`` s of motion played, judged against ``own``
    (:func:`play_reference`, compared) by :func:`judge_counts` (module docstring's rule). The
    own loop has no excuse for the clip's own contacts: its self-collision ticks count every
    contact, the run's those its reference does not make.

    Returns:
        {kind: {"ours", "own", "allowed", "stack", "passed", "names": {name: judge_counts'
        figures}}} for each kind of :data:`JUDGED_KINDS`: ``ours``/``own`` the ticks, ``allowed``
        and ``stack`` summed over the names; ``passed``: no tick past the allowance.
    """
    hard = {j: int(v["ticks"]) for j, v in (violations.get("hard_limit_joints") or {}).items()}
    collided = int(violations["by_type"].get("self_collision", 0))
    per_kind = {
        "hard_limit": judge_counts(hard, own["hard_limit_joints"], own["clip_s"], clip_s),
        "self_collision": judge_counts(
            {"self_collision": collided} if collided else {},
            {"self_collision": own["self_collision_ticks"]} if own["self_collision_ticks"] else {},
            own["clip_s"],
            clip_s,
        ),
    }
    out = {}
    for kind, names in per_kind.items():
        total = {k: sum(v[k] for v in names.values()) for k in ("ours", "own", "allowed", "stack")}
        total["ours"] = int(violations["by_type"].get(kind, 0))  # ticks, not joint-ticks
        total["own"] = own["hard_limit_ticks" if kind == "hard_limit" else "self_collision_ticks"]
        out[kind] = {**total, "passed": total["stack"] == 0, "names": names}
    return out


def judge_hard_limits(result: dict, own: dict) -> tuple[bool, str, dict]:
    """``no_hard_violation`` of an exhibition session against ``own``
    (:func:`own_loop_reference`, compared) by the module docstring's rule.

    Returns:
        (passed, message, figures): figures ``clip_s``, ``own_clip_s``, ``joints`` {joint:
        {ours, own, allowed, stack}} (every joint past a limit in either), ``stack_ticks`` (the
        ticks past the allowances, summed), ``while_down``, ``hard_stops``.
    """
    clip_s = session_clip_s(result)
    ours = result["violations"].get("hard_limit_joints") or {}
    joints = judge_counts(ours, own["hard_limit_joints"], own["clip_s"], clip_s)
    down = result["violations"].get("while_down", {}).get("hard_limit", 0)
    stops = result["runtime"]["by_cause"].get("hard_limit", 0)
    stack = sum(v["stack"] for v in joints.values())
    figures = {
        "clip_s": clip_s,
        "own_clip_s": own["clip_s"],
        "joints": joints,
        "stack_ticks": stack,
        "while_down": int(down),
        "hard_stops": int(stops),
    }
    per_joint = "; ".join(
        f"{j} {v['ours']} (own {v['own']}, allowed {v['allowed']:g})" for j, v in joints.items()
    )
    message = (
        f"hard-limit ticks per joint, ours over {clip_s:.0f} s of clip against the own loop's "
        f"{own['clip_s']:.0f} s "
        f"({own['plays']} plays, {own['falls']} falls): {per_joint or 'none'}; the stack's "
        f"(past the allowance): {stack}"
        + (f"; {down} more lying down after a stop" if down else "")
        + f"; {stops} hard-limit safe stops"
    )
    return stack == 0 and down == 0 and stops == 0, message, figures


def own_guard_share(own: dict, by_design) -> float:
    """The share of the own loop's ticks the replayed guard would have changed by a check not
    in ``by_design``."""
    ticks = sum(
        n for pattern, n in own["guard_patterns"] if any(c not in by_design for c in pattern)
    )
    return ticks / own["ticks"] if own["ticks"] else 0.0


def judge_interventions(result: dict, own: dict, threshold: float) -> tuple[bool, str, dict]:
    """``interventions`` of an exhibition session against ``own`` (module docstring's rule):
    passed at most ``threshold`` of its ticks, or at most ``(1 + MARGIN)`` times the own loop's
    replayed-guard share.

    Returns:
        (passed, message, figures ``{ours, own, allowed}``: shares of ticks).
    """
    iv = result["interventions"]
    by_design = iv.get("by_design", [])
    ours = iv.get("safety", iv["any"])["fraction"]
    share = own_guard_share(own, by_design)
    allowed = max(threshold, (1.0 + MARGIN) * share)
    message = (
        f"{100 * ours:.3f} % of ticks with an intervention; the guard replayed on the own "
        f"loop's ticks would change {100 * share:.3f} % ({own['plays']} plays); allowed "
        f"{100 * allowed:.3f} % (the threshold {100 * threshold:.3f} %, or the own loop's "
        f"share + {100 * MARGIN:g} %)"
    )
    return ours <= allowed, message, {"ours": ours, "own": share, "allowed": allowed}
