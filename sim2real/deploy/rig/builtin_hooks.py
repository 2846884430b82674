"""The built-in command-line hooks of ``deploy-run`` (:mod:`sim2real.deploy.rig.hooks`): ``--print-joints``,
``--video``, ``--viewer`` and ``--ros2``. Importing this module registers them; it imports
neither MuJoCo nor rclpy (their factories do, when the run is built).
"""

from __future__ import annotations

from pathlib import Path

from sim2real.deploy.rig.hooks import RunHook, register_hook


class ViewerHook(RunHook):
    """A viewer called after every tick (it only reads the runtime): the joint printer, the
    video recorder, the passive viewer. Its call returning True (a window closed) ends the run;
    its ``close()``, if any, runs after the run."""

    def __init__(self, name: str, viewer):
        self.name = name
        self.viewer = viewer

    def after_tick(self, runtime) -> bool:
        return bool(self.viewer(runtime))

    def close(self) -> None:
        close = getattr(self.viewer, "close", None)
        if close is not None:
            close()

    def discard(self) -> None:
        """The viewer's ``discard()`` (the video recorder: no partial MP4), else its close."""
        discard = getattr(self.viewer, "discard", None)
        if discard is not None:
            discard()
        else:
            self.close()


class Ros2Hook(RunHook):
    """The run as a ROS 2 node (:class:`sim2real.deploy.ros2.bridge.RuntimeNode`): it spins off the
    control thread and takes each tick from :meth:`after_tick`; its counts are the report's
    ``ros2`` entry."""

    name = "ros2"

    def __init__(self, node):
        self.node = node

    def after_tick(self, runtime) -> None:
        self.node.after_tick(runtime)

    def close(self) -> None:
        self.node.close()

    def contribute(self, report: dict) -> None:
        report["ros2"] = self.node.summary()


# ---------------------------------------------------------------------- --print-joints
def _joint_options(parser) -> None:
    parser.add_argument(
        "--print-joints",
        type=float,
        default=None,
        metavar="HZ",
        help="print q, dq, command and winding temperature per joint HZ times per second",
    )


def joint_printer(args, rig) -> RunHook | None:
    """``--print-joints HZ``: :class:`sim2real.deploy.observe.joint_printer.JointPrinter`."""
    if args.print_joints is None:
        return None
    from sim2real.deploy.observe.joint_printer import JointPrinter

    robot = rig.robot
    printer = JointPrinter(robot.joint_names, args.print_joints, rig.policy.spec.action.mode)
    return ViewerHook("print_joints", printer)


# ---------------------------------------------------------------------- --video
def _video_options(parser) -> None:
    parser.add_argument(
        "--video", type=Path, default=None, help="render the run offscreen to an H.264 MP4"
    )
    parser.add_argument("--camera", default=None, help="--video: MJCF camera name (default: free)")
    parser.add_argument("--fps", type=float, default=30.0, help="--video: frames per second")
    parser.add_argument("--size", default="640x480", help="--video: WIDTHxHEIGHT pixels")


def video(args, rig) -> RunHook | None:
    """``--video PATH``: :func:`sim2real.deploy.observe.video.open_video` (None, and a one-line error,
    without OpenGL)."""
    if args.video is None:
        return None
    from sim2real.deploy.observe.video import open_video

    recorder = open_video(args, rig.robot, rig.backend)
    return None if recorder is None else ViewerHook("video", recorder)


# ---------------------------------------------------------------------- --viewer
def _viewer_options(parser) -> None:
    parser.add_argument(
        "--viewer",
        action="store_true",
        help="MuJoCo's interactive passive viewer (needs a display); lockstep, or --realtime",
    )


def viewer(args, rig) -> RunHook | None:
    """``--viewer``: :class:`sim2real.deploy.observe.viewer.PassiveViewer`, synced after every tick;
    closing its window ends the run."""
    if not args.viewer:
        return None
    from sim2real.deploy.observe.viewer import PassiveViewer

    return ViewerHook("viewer", PassiveViewer(rig.robot, rig.backend))


# ---------------------------------------------------------------------- --ros2
def _ros2_options(parser) -> None:
    parser.add_argument(
        "--ros2",
        action="store_true",
        help="run as a ROS 2 node (extra 'ros2'): publish joint_states, imu, odom (legged), "
        "/diagnostics; take cmd_vel (legged) or goal_point (arm); services ~/stop, ~/resume, "
        "~/reset_faults",
    )
    parser.add_argument(
        "--ros2-namespace", default="", metavar="NS", help="--ros2: the node's namespace"
    )


def ros2_node(args, rig) -> RunHook | None:
    """``--ros2``: :class:`sim2real.deploy.ros2.bridge.RuntimeNode` on the rig's runtime, task and
    intervention monitor."""
    if not args.ros2:
        return None
    from sim2real.deploy.ros2.bridge import RuntimeNode

    node = RuntimeNode(
        rig.runtime,
        namespace=args.ros2_namespace,
        task=rig.task,
        interventions=rig.interventions,
    )
    return Ros2Hook(node)


# ---------------------------------------------------------------------- --record-commands
class RecorderHook(RunHook):
    """Records env 0's commands and encoder readings every tick
    (:class:`sim2real.deploy.observe.command_log.CommandLog`), written when the run ends."""

    name = "record_commands"

    def __init__(self, log):
        self.log = log

    def after_tick(self, runtime) -> None:
        self.log.record(runtime)

    def close(self) -> None:
        path = self.log.close()
        print(f"deploy-run: {self.log.rows} ticks of commands and readings in {path}")

    def discard(self) -> None:
        """Nothing written: the log is written only by :meth:`close`."""


def _record_options(parser) -> None:
    parser.add_argument(
        "--record-commands",
        type=Path,
        default=None,
        metavar="FILE.npz",
        help="record every tick's command and encoder readings (env 0) for sysid",
    )


def recorder(args, rig) -> RunHook | None:
    """``--record-commands FILE``: :class:`RecorderHook`."""
    if args.record_commands is None:
        return None
    from sim2real.deploy.observe.command_log import CommandLog

    mode = rig.policy.spec.action.mode
    return RecorderHook(CommandLog(args.record_commands, rig.robot, mode, args.backend))


register_hook("ros2", "sim2real.deploy.rig.builtin_hooks:ros2_node", _ros2_options)
register_hook("print_joints", "sim2real.deploy.rig.builtin_hooks:joint_printer", _joint_options)
register_hook("video", "sim2real.deploy.rig.builtin_hooks:video", _video_options)
register_hook("viewer", "sim2real.deploy.rig.builtin_hooks:viewer", _viewer_options)
register_hook("record_commands", "sim2real.deploy.rig.builtin_hooks:recorder", _record_options)
