"""The ``[unitree]`` table ``robot-import --floating-base --unitree FAMILY`` writes: how a Unitree
quadruped's joints map to the motor slots of its low-level messages (``deploy-run --backend
unitree``; :class:`sim2real.robots.schema.UnitreeConfig`).

Unitree numbers a quadruped's motors by leg, FR, FL, RR, RL, and within a leg hip, thigh, calf
(unitree_sdk2_python ``example/go2/low_level/unitree_legged_const.py``: ``FR_0`` = 0 ... ``RL_2``
= 11), and its ``foot_force`` by leg in the same order; its descriptions name the joints
``<LEG>_<part>_joint`` (go2_description). A wheel-legged one's wheels ``<LEG>_wheel_joint``
follow, 12 to 15 in the same leg order: the order of the actuators of unitree_mujoco's
``unitree_robots/go2w/go2w.xml`` (its bridge numbers the motors by actuator) and of rl_sar's
``policy/go2w/base.yaml`` ``joint_mapping`` (its ``*_foot_joint``). The slots follow from the
names; a joint named otherwise is refused.

A ``unitree_hg`` humanoid (G1, H1-2) numbers its motors in its descriptions' joint order:
unitree_mujoco's ``unitree_robots/g1/g1_joint_index_dds.md`` lists the G1's 29 motor slots in
the order of ``g1_29dof.xml``'s joints (legs, waist, arms); its ``LowState`` carries no
``foot_force``, so no foot slots are written. The slots are then the joint order, and the note
in the table says where they came from.
"""

from __future__ import annotations

from sim2real.robots.importer.source import RobotImportError

#: Unitree's leg order and the joints of a leg (unitree_legged_const ``LegID``).
LEGS = ("FR", "FL", "RR", "RL")
PARTS = ("hip", "thigh", "calf")
#: A wheel-legged robot's wheel joint part, its motor slots after the legs' (module docstring).
WHEEL = "wheel"
FAMILIES = ("unitree_go", "unitree_hg")


def motor_slot(joint: str) -> int:
    """The motor slot of a joint named ``<LEG>_<part>_joint`` (a wheel's after the legs').

    Raises:
        RobotImportError: another name (the convention quoted).
    """
    leg, _, rest = joint.partition("_")
    part = rest.removesuffix("_joint")
    if leg not in LEGS or part not in (*PARTS, WHEEL) or not rest.endswith("_joint"):
        raise RobotImportError(
            f"--unitree: joint '{joint}' is not named <LEG>_<part>_joint (LEG one of "
            f"{', '.join(LEGS)}; part one of {', '.join((*PARTS, WHEEL))}): its motor slot is "
            "unknown"
        )
    if part == WHEEL:
        return len(LEGS) * len(PARTS) + LEGS.index(leg)
    return 3 * LEGS.index(leg) + PARTS.index(part)


def motor_slots(family: str, joint_names: list[str]) -> list[int]:
    """The motor slot of each joint (module docstring): ``unitree_hg`` the joint order,
    ``unitree_go`` from the names (:func:`motor_slot`).

    Raises:
        RobotImportError: an unknown family, or a ``unitree_go`` joint off Unitree's naming.
    """
    if family not in FAMILIES:
        raise RobotImportError(f"--unitree {family}: expected one of {', '.join(FAMILIES)}")
    if family == "unitree_hg":
        return list(range(len(joint_names)))
    return [motor_slot(j) for j in joint_names]


def foot_slot(foot: str) -> int:
    """The ``foot_force`` slot of a foot link named ``<LEG>_...``.

    Raises:
        RobotImportError: a name without one of Unitree's legs first.
    """
    leg = foot.partition("_")[0]
    if leg not in LEGS:
        raise RobotImportError(
            f"--unitree: foot '{foot}' does not start with a leg ({', '.join(LEGS)}_)"
        )
    return LEGS.index(leg)


def unitree_lines(
    family: str,
    joint_names: list[str],
    feet: list[str],
    damping_kd: float,
    ramp_kp: float | None,
    ramp_kd: float | None,
) -> list[str]:
    """The ``[unitree]`` table's lines (module docstring); the gains' sources are the header's
    ``--note`` lines.

    Raises:
        RobotImportError: an unknown family, a joint or foot off Unitree's naming, a gain that is
            not positive (the damping and ramp kd may be 0).
    """
    if family not in FAMILIES:
        raise RobotImportError(f"--unitree {family}: expected one of {', '.join(FAMILIES)}")
    for flag, value, positive in (
        ("--unitree-damping-kd", damping_kd, False),
        ("--unitree-ramp-kp", ramp_kp, True),
        ("--unitree-ramp-kd", ramp_kd, False),
    ):
        if value is not None and (value < 0 or (positive and value == 0)):
            raise RobotImportError(f"{flag}: expected a gain >= 0 (kp > 0), got {value}")
    slots = motor_slots(family, joint_names)
    if family == "unitree_hg":
        how = [
            "# motor slots in the joint order (unitree_hg humanoids: unitree_mujoco's",
            "# g1_joint_index_dds.md); their LowState has no foot_force.",
        ]
        feet_line = []
    else:
        how = [
            "# motor slots in Unitree's leg order FR, FL, RR, RL (hip, thigh, calf: unitree_sdk2's",
            "# unitree_legged_const), foot_force slots in the same leg order.",
        ]
        if any(name.endswith(f"_{WHEEL}_joint") for name in joint_names):
            how[1:] = [
                "# unitree_legged_const; wheels after the legs, as go2w.xml's actuators), foot_force",
                "# slots in the same leg order.",
            ]
        feet_line = ["foot_index = [" + ", ".join(str(foot_slot(f)) for f in feet) + "]"]
    lines = [
        "",
        "# deploy-run --backend unitree (robot-import --unitree; out of the description hash):",
        *how,
        "[unitree]",
        f'family = "{family}"',
        "motor_index = [" + ", ".join(map(str, slots)) + "]",
        *feet_line,
        "motor_mode = 1  # 0x01, servo (FOC) on: unitree_sdk2's low-level examples",
        f"damping_kd = {damping_kd:g}  # N m s/rad with kp 0 (--unitree-damping-kd)",
        "ramp_time = 2.0  # s: unitree_rl_gym deploy_real's move to the default pose",
    ]
    if ramp_kp is not None:
        lines.append(f"ramp_kp = {ramp_kp:g}  # N m/rad (--unitree-ramp-kp)")
    if ramp_kd is not None:
        lines.append(f"ramp_kd = {ramp_kd:g}  # N m s/rad (--unitree-ramp-kd)")
    return lines
