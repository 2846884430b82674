"""The command line of ``deploy-run``: its argument parser (:func:`build_parser`); the backends
``--backend`` chooses from, and their options, come from :mod:`sim2real.deploy.backends.registry`
(the ros2 backend, a floor above the registry, registered by this module's import of
:mod:`sim2real.deploy.ros2.options`).

The options are read before anything heavy is imported: this module imports neither MuJoCo nor
numba (:mod:`sim2real.deploy.runtime.clock` is MuJoCo-free), since ``deploy-run`` chooses MuJoCo's OpenGL
backend after parsing. What the options do, and the exit codes: :mod:`sim2real.deploy.cli.deploy_run`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from sim2real.deploy.backends.registry import add_backend_options
from sim2real.deploy.cli.run_operator import add_operator_options
from sim2real.deploy.rig.hooks import add_hook_options
from sim2real.deploy.ros2 import options as ros2_options
from sim2real.deploy.runtime.clock import WAIT_MODES
from sim2real.deploy.tasks.heading import HEADING_GAIN
from sim2real.robots.errors import Sim2RealError


class BadOption(Sim2RealError, ValueError):
    """A command line deploy-run's parser refuses (an unknown option, a value of the wrong type
    or choice, a missing one); the message is argparse's, naming the option."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # bad input, exit 3: argparse's exit 2 is a latched fault here
        raise BadOption(message)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser of ``deploy-run``'s options (:func:`sim2real.deploy.cli.deploy_run.deploy_run_main`),
    with the options of the backend ``argv`` chooses (:mod:`sim2real.deploy.backends.registry`; default
    ``sys.argv``). A bad command line raises :class:`BadOption` (deploy-run: one line, exit 3),
    not argparse's usage and exit 2."""
    p = _Parser(
        prog="deploy-run",
        description="Run an exported ONNX policy through the safety runtime.",
        epilog="Exit codes: 0 clean, 1 hard violation, 2 latched fault, 3 bad input, "
        "4 simulation diverged.",
    )
    ros2_options.register()  # --backend ros2, after the registry's own (registered once)
    add_backend_options(p, argv)
    p.add_argument("--robot", default="arm3", help="shipped robot name or robot.toml path")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--policy",
        action="append",
        metavar="[NAME=]FILE",
        help="ONNX policy (made by policy-export); repeat with names for an operator's switching "
        "(--policy walk=go2.onnx --policy stand=go2_stand.onnx); the first starts",
    )
    source.add_argument(
        "--excitation",
        default=None,
        metavar="default|FILE",
        help="instead of a policy, a scripted excitation for identification (chirps and steps "
        "per joint alone, then together; an excitation TOML's keys: "
        "sim2real.deploy.policy.excitation.Excitation); with --record-commands: docs/sysid.md",
    )
    p.add_argument("--spec", default=None, help="PolicySpec JSON for an ONNX without our metadata")
    p.add_argument(
        "--inference",
        choices=("async", "sync"),
        default="async",
        help="a chunked (LeRobot) policy's network call: async (default) runs it on a worker "
        "thread beside the servo loop, which keeps its period; it costs one policy period of "
        "latency (40 ms at 25 fps): the chunk asked at a policy tick is taken at the next, its "
        "first action dropped as late, the previous chunk's last action held meanwhile; sync "
        "runs it inside the servo tick (no added latency; that tick overruns by the call's time)",
    )
    p.add_argument("--duration", type=float, default=60.0, help="seconds of (simulated) time")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--envs", type=int, default=1, help="robots simulated in lockstep")
    p.add_argument("--realtime", action="store_true", help="wall clock with absolute deadlines")
    _add_realtime_options(p)
    _add_task_options(p)
    p.add_argument(
        "--inject",
        action="append",
        default=[],
        metavar="KIND[=MAGNITUDE]@SECONDS[:DURATION]",
        help="fault injection (sim): dropout, stale, nan-action, latency, push, cable; "
        "MAGNITUDE: latency ticks (default 10), push / cable force N (default 20 / 10)",
    )
    p.add_argument("--report", type=Path, default=None, help="write the summary as JSON")
    p.add_argument(
        "--telemetry",
        type=Path,
        default=None,
        help="write downsampled MCAP (with the foxglove extra: link poses, joint states, "
        "commands and guard events in Foxglove's schemas)",
    )
    add_operator_options(p)
    add_hook_options(p)  # --ros2, --print-joints, --video, --viewer (sim2real.deploy.rig.hooks)
    return p


def _add_realtime_options(p: argparse.ArgumentParser) -> None:
    """Add the real-time options: overrun limit, wait mode, priority, CPUs, memory lock."""
    p.add_argument(
        "--overrun-limit",
        type=float,
        default=None,
        help="wall clock: fraction of the control periods of the last second the loop may miss "
        "before a safe stop (default: position mode 0.5, velocity and torque 0.25); a shorter "
        "stall is ridden through, the drives holding the last command",
    )
    p.add_argument(
        "--wait",
        choices=WAIT_MODES,
        default=None,
        help="wall clock: how to wait for each deadline: sleep, hybrid (sleep, then busy-wait "
        "the last 150 us; default) or spin (busy-wait the whole period: one core kept hot)",
    )
    p.add_argument("--spin", action="store_true", help="wall clock: the same as --wait spin")
    p.add_argument(
        "--rt-priority",
        type=int,
        default=None,
        metavar="N",
        help="wall clock: run the loop at SCHED_FIFO priority N (1..99) where permitted "
        "(CAP_SYS_NICE or an rtprio limit); otherwise a one-line notice and normal priority",
    )
    p.add_argument(
        "--cpu",
        default=None,
        metavar="N[,M]",
        help="run the loop on these CPUs (sched_setaffinity); a CPU the process may not use "
        "is an error (exit 3)",
    )
    p.add_argument(
        "--lock-memory",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="lock the process's memory (mlockall) where permitted (CAP_IPC_LOCK or a memlock "
        "limit); default: on with --rt-priority",
    )
    p.add_argument(
        "--require-rt",
        action="store_true",
        help="a refused --rt-priority or memory lock is an error (exit 3), not a notice",
    )


def parse_terrain_option(args) -> None:
    """``args.terrain`` (``--terrain``'s text, or None) made its tile draw
    (:func:`sim2real.eval.world.terrain.parse_terrain`) in place. Read after the parser, not as
    its ``type``: argparse answers a bad ``type`` with its usage and exit 2, the code of a
    latched fault; deploy-run answers bad input in one line with exit 3.

    Raises:
        ValueError: an unknown kind, a malformed size or level, or one outside legged_gym's
            difficulties (the message names ``--terrain``, the value and what is expected).
    """
    if args.terrain is not None:
        from sim2real.eval.world.terrain import parse_terrain

        args.terrain = parse_terrain(args.terrain)


def _add_task_options(p: argparse.ArgumentParser) -> None:
    """Add the task options: the legged velocity command and heading hold, the terrain, the
    reach goals; a clip's (:func:`_add_motion_options`) and a camera's
    (:func:`_add_camera_options`)."""
    _add_motion_options(p)
    _add_camera_options(p)
    p.add_argument(
        "--command",
        default=None,
        help="legged robots: velocity command VX,VY,WZ (m/s, m/s, rad/s, base frame)",
    )
    p.add_argument(
        "--heading-hold",
        type=float,
        default=HEADING_GAIN,
        metavar="GAIN",
        help="legged robots, a --command whose yaw rate WZ is 0: hold the heading the robot had "
        "when it began to walk, giving the policy the yaw rate GAIN * heading error (1/s, "
        "clipped to 1 rad/s; legged_gym's heading command, default %(default)s); 0: give the "
        "policy the command as it is",
    )
    p.add_argument(
        "--terrain",
        default=None,
        metavar="KIND:SIZE|KIND@LEVEL",
        help="--backend sim, legged robots: the robot starts on legged_gym terrain tiles of one "
        "kind instead of the plane (stairs_up:0.10 m steps, stairs_down:0.10, slope_up:15deg, "
        "slope_down:15deg, rough_slope@5, discrete:0.10; sim2real/eval/world/terrain.py)",
    )
    p.add_argument("--goal-period", type=float, default=4.0, help="s between new goals")
    p.add_argument("--goal", default=None, help="fixed goal X,Y,Z (m, base frame)")
    p.add_argument(
        "--success-time",
        type=float,
        default=3.0,
        help="a goal counts as reached within this many seconds",
    )


def _plays(text: str) -> int:
    """``--own-loop-plays``: an integer >= 0."""
    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return n


def _add_motion_options(p: argparse.ArgumentParser) -> None:
    """Add a motion-tracking policy's options: the clip, its rate, what follows it, its start."""
    p.add_argument(
        "--motion",
        default=None,
        metavar="CLIP",
        help="motion-tracking policies: the reference clip in place of the one its contract "
        "names beside it: rl_sar CSV, BeyondMimic or holosoma NPZ, a holosoma or BeyondMimic "
        "ONNX's motion (recognised by extension and content; docs/motion-tracking.md)",
    )
    p.add_argument(
        "--motion-fps",
        default=None,
        metavar="HZ",
        help="the --motion clip's rate, Hz, in place of the contract's",
    )
    p.add_argument(
        "--motion-playback",
        choices=("stand", "once", "loop", "hold"),
        default=None,
        help="at the clip's end, without a policy to hand over to (--after-clip): a transition "
        "to the home pose the policy tracks, then home (stand, the default: holosoma's "
        "default_pose_append), hold its last frame (once, hold) or start it again (loop); a "
        "hold is judged (the base's travel after the clip)",
    )
    p.add_argument(
        "--after-clip",
        default=None,
        metavar="NAME",
        help="hand the robot to the policy --policy NAME=FILE at the clip's end, as rl_sar's "
        "fsm hands its dance to its locomotion policy (default: a clip run's second --policy, "
        "without --operator); 'default-pose': no second policy, the policy off and the PD "
        "loop holding the home pose, ramped to from its last target (unitree_rl_gym's "
        "deploy); one robot (--envs 1)",
    )
    p.add_argument(
        "--after-clip-blend",
        type=float,
        default=None,
        metavar="S",
        help="s the hand-over of --after-clip blends the targets over (default 0: at once, as "
        "rl_sar's); with default-pose, s of the ramp to home (default 2, unitree_rl_gym's "
        "move_to_default_pos)",
    )
    p.add_argument(
        "--motion-stand-s",
        type=float,
        default=2.0,
        metavar="S",
        help="s of --motion-playback stand's transition to home (holosoma's default 2)",
    )
    p.add_argument(
        "--motion-start-after",
        type=float,
        default=0.0,
        metavar="S",
        help="s of RUNNING before the clip starts, the policy holding its first frame meanwhile "
        "(as the operator starts a clip from a stand; a robot let off its gantry first)",
    )
    p.add_argument(
        "--own-loop-plays",
        type=_plays,
        default=1,
        metavar="N",
        help="a tracking run with hard-limit or self-collision ticks: plays of its motion in the "
        "policy's own loop, whose ticks the run's are judged against (0: not compared; "
        "docs/motion-tracking.md)",
    )


def parse_camera_source_option(args) -> None:
    """``args.camera_source`` (``--camera-source``'s texts) made
    :class:`~sim2real.deploy.backends.camera.options.CameraSource` values in place, after the
    parser as :func:`parse_terrain_option` (one line and exit 3 for a bad one).

    Raises:
        ValueError: a value of another form than NAME=KIND:WHERE[,loop] (CameraError, naming
            ``--camera-source`` and the expected form).
    """
    from sim2real.deploy.backends.camera.options import parse_camera_source

    texts = getattr(args, "camera_source", None) or []
    args.camera_source = [parse_camera_source(t) for t in texts]


def _add_camera_options(p: argparse.ArgumentParser) -> None:
    """Add a camera's options: on hardware (any backend) the source of its frames; with
    ``--backend sim`` and no source, the plant camera's rate, latency and faults (depth or
    colour)."""
    p.add_argument(
        "--camera-source",
        action="append",
        default=[],
        metavar="NAME=KIND:WHERE",
        help="the frames of the policy's camera NAME (its images entry's camera) from hardware, "
        "with any backend, in place of the plant's rendering; once per camera of a policy that "
        "reads several: opencv:INDEX, opencv:/dev/videoN, "
        "opencv:FILE (a video played at its rate), realsense:, realsense:SERIAL, "
        "realsense:FILE.bag, ros2:/TOPIC (sensor_msgs/Image; /TOPIC/compressed: "
        "CompressedImage); ',loop' plays a file again at its end (docs/cameras.md)",
    )
    p.add_argument(
        "--camera-rate",
        type=float,
        default=None,
        metavar="HZ",
        help="--backend sim, a policy with an image input (depth or RGB): the camera's frame rate "
        "(default the rate its spec's images entry names; sim2real/deploy/backends/sim/camera.py)",
    )
    p.add_argument(
        "--camera-latency",
        type=float,
        default=None,
        metavar="S",
        help="--backend sim: s from a frame's capture to its delivery (default the latency its "
        "spec's images entry names)",
    )
    p.add_argument(
        "--camera-faults",
        choices=("none", "drawn"),
        default="none",
        help="--backend sim: 'drawn', the run's camera faults (dropped, late and frozen frames, "
        "a covered lens, a knocked mount, a lighting change) drawn from --seed "
        "(CameraFaultRanges); default none",
    )


#: Options whose value may start with '-' (a vector with a negative first entry).
VECTOR_OPTIONS = ("--command", "--goal")


def attach_vectors(argv: Sequence[str] | None) -> list[str]:
    """``argv`` with ``--command -0.5,0,0`` written ``--command=-0.5,0,0`` (argparse takes a
    value starting with '-' that is not a plain negative number for an option, and refused
    a backwards walk with "expected one argument"); ``argv`` None: ``sys.argv[1:]``."""
    argv = sys.argv[1:] if argv is None else list(argv)
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in VECTOR_OPTIONS and i + 1 < len(argv) and argv[i + 1].startswith("-"):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


def split_passthrough(argv: Sequence[str] | None) -> tuple[list[str], list[str]]:
    """``(own, rest)``: the arguments before a ``--`` (this command's) and after it (passed on
    to the command it runs: deploy-run, soak-test); ``argv`` None: ``sys.argv[1:]``."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if "--" not in argv:
        return argv, []
    cut = argv.index("--")
    return argv[:cut], argv[cut + 1 :]
