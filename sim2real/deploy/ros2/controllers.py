"""ros2_control's forward command controllers: which one takes which control mode, its topic, and
the joint order of its command array.

A ``forward_command_controller/ForwardCommandController`` (the ``forward_position_controller``,
``forward_velocity_controller`` and ``forward_effort_controller`` of the ros2_control demos and
of most robot bring-ups) takes ``std_msgs/Float64MultiArray`` on ``<controller>/commands``, one
value per joint in the order of its ``joints`` parameter, for its ``interface_name`` (position,
velocity or effort). :func:`controller_joints` reads that order from the controller manager's
YAML (``<controller>: ros__parameters: joints: [...]``), as the robot's bring-up loads it;
:func:`command_order` checks it against the robot folder.
"""

from __future__ import annotations

from pathlib import Path

import yaml

#: The forward command controller of each control mode (the ros2_control demos' names).
FORWARD_CONTROLLERS = {
    "position": "forward_position_controller",
    "velocity": "forward_velocity_controller",
    "torque": "forward_effort_controller",
}
#: The command interface each control mode writes (ros2_control's hardware_interface names).
INTERFACES = {"position": "position", "velocity": "velocity", "torque": "effort"}


def command_topic(controller: str) -> str:
    """``'<controller>/commands'``: where a forward command controller takes its commands."""
    return f"{controller}/commands"


def controller_joints(path: str | Path, controller: str, mode: str) -> list[str]:
    """The ``joints`` of ``controller`` in a controller manager's YAML ``path``.

    Raises:
        ValueError: the file does not parse, has no ``<controller>: ros__parameters: joints``
            list of names, or its ``interface_name`` is not the mode's (``INTERFACES``); the
            message names the file, the field and the value expected.
    """
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not YAML ({exc})") from None
    field = f"{controller}.ros__parameters.joints"
    params = ((doc or {}).get(controller) or {}).get("ros__parameters") or {}
    joints = params.get("joints")
    if not isinstance(joints, list) or not joints or not all(isinstance(j, str) for j in joints):
        raise ValueError(f"{path}: field '{field}': expected a list of joint names, got {joints!r}")
    interface = params.get("interface_name")
    if interface is not None and interface != INTERFACES[mode]:
        raise ValueError(
            f"{path}: field '{controller}.ros__parameters.interface_name' is {interface!r}; a "
            f"{mode}-mode policy writes {INTERFACES[mode]!r}"
        )
    return joints


def command_order(robot_joints: list[str], controller_joints: list[str], source: str) -> list[int]:
    """For each of the controller's joints, its index in the robot's joint order.

    Raises:
        ValueError: a joint of the robot the controller does not command, a joint the robot
            does not have, or a joint listed twice (``source`` names where the list came from).
    """
    missing = [j for j in robot_joints if j not in controller_joints]
    unknown = [j for j in controller_joints if j not in robot_joints]
    twice = sorted({j for j in controller_joints if controller_joints.count(j) > 1})
    if missing or unknown or twice:
        parts = []
        if missing:
            parts.append(f"does not command the robot's joints {missing}")
        if unknown:
            parts.append(f"commands joints the robot does not have {unknown}")
        if twice:
            parts.append(f"lists {twice} twice")
        raise ValueError(
            f"{source}: the controller {'; '.join(parts)}; the robot's joints: {robot_joints}"
        )
    return [robot_joints.index(j) for j in controller_joints]
