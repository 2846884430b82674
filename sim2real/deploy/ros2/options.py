"""``deploy-run --backend ros2``: a ros2_control robot, its registration and options
(:mod:`sim2real.deploy.backends.registry`)."""

from __future__ import annotations

from sim2real.deploy.backends.real_robot import refuse_simulation_options
from sim2real.deploy.backends.registry import backends, register_backend


def add_options(group) -> None:
    """The ros2_control options: namespace, controller, its joint order, the state timeout."""
    group.add_argument(
        "--ros2-robot-namespace",
        default="",
        metavar="NS",
        help="namespace of the robot's joint_states and controller topics (default: the root)",
    )
    group.add_argument(
        "--controller",
        default=None,
        help="the forward command controller to write (default: forward_position_controller, "
        "forward_velocity_controller or forward_effort_controller by the policy's mode)",
    )
    group.add_argument(
        "--controllers-yaml",
        default=None,
        metavar="FILE",
        help="the controller manager's YAML: the controller's 'joints' give the command order "
        "(default: the robot folder's joint order)",
    )
    group.add_argument(
        "--state-timeout", type=float, default=5.0, help="s to wait for the first joint_states"
    )


def make(args, robot, mode: str):
    """A ros2_control robot in ``args.ros2_robot_namespace``."""
    refuse_simulation_options(args, "ros2", "python -m sim2real.deploy.ros2.emulator --help")
    from sim2real.deploy.ros2.backend import Ros2ControlBackend
    from sim2real.deploy.ros2.context import require_ros2
    from sim2real.deploy.ros2.controllers import FORWARD_CONTROLLERS, controller_joints

    require_ros2()
    controller = args.controller or FORWARD_CONTROLLERS[mode]
    joints = None
    if args.controllers_yaml:
        joints = controller_joints(args.controllers_yaml, controller, mode)
    return Ros2ControlBackend(
        robot,
        mode,
        namespace=args.ros2_robot_namespace,
        controller=controller,
        joints=joints,
        state_timeout=args.state_timeout,
    )


def register() -> None:
    """Register ``--backend ros2`` (once; after the registry's built-in backends, in their order):
    deploy-run's parser calls it (:mod:`sim2real.deploy.cli.run_parser`), a floor above the
    registry, which names no module of this room."""
    if "ros2" not in backends():
        register_backend(
            "ros2",
            "a ros2_control robot: joint_states in, a forward command controller out (wall "
            "clock only)",
            "sim2real.deploy.ros2.options:make",
            add_options,
        )
