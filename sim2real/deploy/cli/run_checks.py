"""deploy-run's refusals before anything opens, and its safety net after.

Every input of a run is read and checked before any of its outputs opens (the telemetry's MCAP,
the video, the recorded commands, the report): :func:`check_outputs` (each output's folder),
:func:`check_options` (the values read only once the run is built: ``--command``, ``--size``,
``--fps``, ``--motion-fps``). Should a run be refused or end in an error all the same,
:func:`discard` removes what it had opened, so that a refused run leaves nothing behind and says
why in one line (exit 3).
"""

from __future__ import annotations

import contextlib
from pathlib import Path

#: deploy-run's output options: (flag, attribute of the parsed options).
OUTPUTS = (
    ("--report", "report"),
    ("--telemetry", "telemetry"),
    ("--video", "video"),
    ("--record-commands", "record_commands"),
)


def check_outputs(args) -> None:
    """Refuse an output (:data:`OUTPUTS`) that names a folder, or whose folder does not exist,
    before the run (the report and the recorded commands are written only when it ends).

    Raises:
        ValueError: naming the option, the path and what was expected.
    """
    for flag, attr in OUTPUTS:
        path = getattr(args, attr, None)
        if path is None:
            continue
        path = Path(path)
        if path.is_dir():
            raise ValueError(f"{flag} {path}: a folder; expected a file name")
        if not path.parent.is_dir():
            raise ValueError(f"{flag} {path}: expected a file in an existing folder")


def check_options(args, robot) -> None:
    """Check the options the run reads only once it is built: a legged ``robot``'s
    ``--command`` (an arm ignores it), ``--video``'s ``--size`` and ``--fps``, ``--motion-fps``.

    Raises:
        ValueError: ``--command`` not VX,VY,WZ; a bad ``--size`` or ``--fps`` with ``--video``;
            ``--motion-fps`` not a number > 0;
            ``--terrain`` off the simulated backend or for a robot without a floating base.
    """
    from sim2real.deploy.tasks.task import follows_velocity_commands

    if getattr(args, "terrain", None) is not None:
        if args.backend != "sim":
            raise ValueError(
                f"--terrain: the ground of --backend sim only, got --backend {args.backend}"
            )
        if not follows_velocity_commands(robot):
            raise ValueError(
                f"--terrain: robot {robot.name} does not walk; terrain is for legged robots"
            )

    if args.command is not None and follows_velocity_commands(robot):
        from sim2real.deploy.tasks.commands import parse_command

        parse_command(args.command)
    if getattr(args, "video", None) is not None:
        import math

        from sim2real.deploy.observe.video import parse_size

        parse_size(args.size)
        if not (math.isfinite(args.fps) and args.fps > 0):
            raise ValueError(f"--fps {args.fps:g}: expected frames per second > 0")
    if getattr(args, "motion_fps", None) is not None:
        _motion_fps(args.motion_fps)


def _motion_fps(value: str) -> float:
    """``--motion-fps``'s rate, Hz (a finite number > 0); a ValueError naming the flag."""
    import math

    try:
        fps = float(value)
    except ValueError:
        fps = math.nan
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(
            f"--motion-fps {value}: expected the clip's frames per second, a number > 0"
        )
    return fps


def discard(rig=None, telemetry=None, source=None) -> None:
    """The safety net of a refused or failed run: the rig's hooks discarded (no partial video;
    :meth:`~sim2real.deploy.rig.rig.Rig.discard`), the telemetry's ``.part`` removed
    (:meth:`~sim2real.deploy.observe.telemetry.Telemetry.discard`), the operator's source closed.
    An error while cleaning up is dropped: the run's own error is the one reported."""
    for release in (
        getattr(rig, "discard", None),
        getattr(telemetry, "discard", None),
        getattr(source, "close", None),
    ):
        if release is not None:
            with contextlib.suppress(Exception):
                release()
