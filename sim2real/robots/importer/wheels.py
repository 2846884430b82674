"""A floating-base robot on wheels as ``robot-import --floating-base`` writes it.

A floating-base robot's continuous joint (an MJCF hinge without ``range``, a URDF ``continuous``
joint; robot.toml ``continuous = true``) is a wheel: unitree_mujoco's Go2-W (``go2w.xml``) ends
each leg in one. Such a robot is written ``kind = "wheel_legged"``
(:mod:`sim2real.deploy.kinds.wheel_legged`: its wheels checked on speed and torque, never on an
angle, braked to 0 rad/s in a safe stop), so that the policy that drives its wheels by speed
(rl_sar's ``policy/go2w/robot_lab``: ``rl_kp`` 0 on its ``wheel_indices``, a velocity target)
runs on the folder as written. A wheel whose ``kp`` is 0 (``--kp JOINT=0``, or the
``--drive-from`` policy's: rl_sar's ``rl_kp`` on its ``wheel_indices``) is written a velocity
drive, ``drive = "velocity"`` (``tau = kd (v_target - dq)``: its ``kd`` must be positive), with no
PD-target limits (:func:`check_velocity_drives`).
"""

from __future__ import annotations

import math

import numpy as np

from sim2real.robots.importer.source import RobotImportError

#: robot.toml's ``kind`` of a floating-base robot with wheels.
WHEEL_LEGGED = "wheel_legged"


def wheel_joints(joint_names: list[str], limits: dict) -> list[str]:
    """The continuous joints among ``joint_names``: ``limits`` maps a joint to (lower, upper rad,
    velocity rad/s, effort N m), a continuous joint's lower or upper infinite."""
    return [j for j in joint_names if math.isinf(limits[j][0]) or math.isinf(limits[j][1])]


def kind_lines(wheels: list[str]) -> list[str]:
    """robot.toml's ``kind`` line and its comment for a floating-base robot with ``wheels``
    (joint names); none without."""
    if not wheels:
        return []
    return [
        f"# a legged robot on wheels, its {len(wheels)} continuous joints (robot-import): checked on",
        "# their speed and torque, braked to 0 rad/s in a safe stop; a policy drives them by",
        "# speed (kp 0, tau = kd (v_target - dq)): sim2real.deploy.kinds.wheel_legged",
        f'kind = "{WHEEL_LEGGED}"',
    ]


def check_velocity_drives(
    joint_names: list[str], kp, wheels: list[str], sources: dict
) -> np.ndarray:
    """(n,) bool: the joints of ``joint_names`` whose ``kp`` (N m/rad, (n,)) is 0, velocity
    drives; ``sources`` maps a joint to where its kp came from.

    Raises:
        RobotImportError: kp 0 on a joint that is not continuous (not in ``wheels``), naming it
            and its source.
    """
    speed = np.asarray(kp, dtype=np.float64) == 0
    off = [j for j, s in zip(joint_names, speed, strict=True) if s and j not in wheels]
    if off:
        raise RobotImportError(
            f"kp 0 on {', '.join(off)} ({sources.get(off[0], 'unknown source')}): only a "
            "continuous joint (a wheel) is driven by speed; expected kp > 0"
        )
    return speed
