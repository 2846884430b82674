"""A policy over part of a robot's joints, run on the whole robot (:func:`widen`).

Unitree's G1 has 29 joints (35 motor slots); unitree_rl_gym's G1 policy drives its 12 leg
joints, and Unitree's deploy code (``deploy_real.py``: the arms and waist at their default
angles with their ``arm_waist_kps`` / ``arm_waist_kds``) holds the rest. A spec whose
``joint_names`` are some of the robot's joints (in any order) is widened to one over every joint
of the robot:

- ``joint_names``: the robot's.
- observation blocks read the same joints as before (their ``joints`` renumbered into the
  robot's order), so the observation is unchanged entry for entry;
- the action's ``joints`` name, per graph output, the robot joint it drives; a joint no output
  drives has action 0, its target is its ``offset``: the robot's home pose (``robot.toml``
  ``control.home``), with scale 0;
- ``drive`` (the training's PD gains and default pose, when recorded) is completed with the
  robot's own ``kp``, ``kd`` and home for the held joints.

The held joints stay the runtime's like any other: estimated, guarded against their limits,
smoothed, and ramped to home in the bring-up.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

from sim2real.deploy.spec.drive import DriveSpec

if TYPE_CHECKING:
    from sim2real.deploy.spec.policy_spec import PolicySpec
    from sim2real.robots import Robot


def is_subset(spec: PolicySpec, robot: Robot) -> bool:
    """Whether ``spec`` drives some but not all of ``robot``'s joints: its ``joint_names`` are
    distinct joints of the robot, fewer than the robot has."""
    names = tuple(spec.joint_names)
    return (
        len(names) < robot.n_joints
        and len(set(names)) == len(names)
        and set(names) <= set(robot.joint_names)
    )


def run_spec(spec: PolicySpec, robot: Robot) -> PolicySpec:
    """The spec ``robot`` runs: ``spec`` widened (:func:`widen`) when it is a policy over part
    of this robot (same robot name, :func:`is_subset`), else ``spec`` itself (whose
    ``check_robot`` then names any mismatch)."""
    if spec.robot == robot.name and is_subset(spec, robot):
        return widen(spec, robot)
    return spec


def widen(spec: PolicySpec, robot: Robot) -> PolicySpec:
    """The spec over every joint of ``robot`` that runs ``spec``'s policy unchanged (module
    docstring); ``spec`` itself when it already names the robot's joints.

    Args:
        spec: A validated spec whose ``joint_names`` are some of ``robot``'s joints.
        robot: The robot it runs on.

    Returns:
        A validated :class:`~sim2real.deploy.spec.policy_spec.PolicySpec` with ``joint_names ==
        robot.joint_names``, the same ``obs_dim`` and ``action.outputs``.

    Raises:
        SpecError: a joint of the spec the robot does not have (naming it), or the widened spec
            is invalid.
    """
    from sim2real.deploy.spec.policy_spec import SpecError

    if tuple(spec.joint_names) == robot.joint_names:
        return spec
    missing = [j for j in spec.joint_names if j not in robot.joint_names]
    if missing:
        raise SpecError(
            f"joint_names: the robot '{robot.name}' has no joint {missing[0]!r}; its joints are "
            f"{list(robot.joint_names)}"
        )
    index = [robot.joint_names.index(j) for j in spec.joint_names]  # spec joint -> robot joint
    n = robot.n_joints
    blocks = tuple(
        replace(b, joints=tuple(index[j] for j in b.joints)) if b.joints else b
        for b in spec.observation_blocks
    )
    a = spec.action
    outputs = a.joints if a.joints else tuple(range(a.size))  # output -> spec joint
    home = [float(h) for h in robot.config.control.home]
    scale, offset = [0.0] * n, list(home)
    for j, r in enumerate(index):
        scale[r], offset[r] = a.scale[j], a.offset[j]
    action = replace(
        a,
        size=n,
        scale=tuple(scale),
        offset=tuple(offset),
        joints=tuple(index[j] for j in outputs),
    )
    drive = spec.drive
    if drive is not None and not drive.empty:
        own = {
            "kp": [float(c.kp) for c in robot.config.joints],
            "kd": [float(c.kd) for c in robot.config.joints],
            "default_pose": home,
        }
        fields = {}
        for name, values in (
            ("kp", drive.kp),
            ("kd", drive.kd),
            ("default_pose", drive.default_pose),
        ):
            if not values:
                fields[name] = ()
                continue
            full = list(own[name])
            for j, r in enumerate(index):
                full[r] = values[j]
            fields[name] = tuple(full)
        drive = DriveSpec(**fields)
    wide = replace(
        spec, joint_names=robot.joint_names, observation_blocks=blocks, action=action, drive=drive
    )
    wide.validate()
    return wide
