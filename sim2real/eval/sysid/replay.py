"""A logged run's commands replayed open-loop through the plant: what the plant's joints do under
exactly the commands the robot was sent (:func:`replay`), and how far that is from what the robot
read (:func:`reading_errors`).

The replay starts at rest at the log's first readings and steps one control period per row of
its timeline (:func:`timeline`): the log's ticks, each writing its command; or, for a robot that
runs its own fixed-rate update loop (a ros2_control robot: the log's ``robot_loop``), that
loop's updates, each writing the newest command sent before it, as the robot's loop did. It
compares each reading with the plant's true joint position at the row it was sampled (its
stamp), so the log's sensor latency and the loops' phase are no error of the motors.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.robots.plant_motors import PlantMotors


def check_log(robot, meta: dict) -> None:
    """Raise ``ValueError`` unless the log ``meta`` is of ``robot``'s joints and control period."""
    if meta["joint_names"] != list(robot.joint_names):
        raise ValueError(
            f"the log's joints {meta['joint_names']} are not the robot {robot.name}'s "
            f"{list(robot.joint_names)}"
        )
    if abs(meta["control_period"] - robot.control_period) > 1e-9:
        raise ValueError(
            f"the log's control period {meta['control_period']} s is not the robot's "
            f"{robot.control_period} s"
        )


def timeline(arrays: dict, dt: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The replay's rows: ``(times, commands, first)``: ``times`` (rows + 1,) s on the log's
    clock, when each row starts (the last: when the last ends); ``commands`` (rows,) int, the
    log's tick whose command each row writes; ``first``, the tick whose readings start the
    replay.

    A log of the robot's own update loop (``loop_stamp`` and ``write_time``,
    :mod:`sim2real.deploy.observe.command_log`) has a row per update: the updates' times
    fitted as a line through the stamps (each stamp a whole number of ``dt`` after the first,
    the line's slope the loop's period as this computer's clock measures it), from the first
    stamped reading to the last; each row writes the newest command sent at or before it
    (before the first command, the first). Any other log has a row per tick, starting at its
    read time.

    Raises:
        ValueError: a loop log with fewer than two stamped readings.
    """
    reads = arrays["read_time"]
    if "loop_stamp" not in arrays:
        return np.append(reads, reads[-1] + dt), np.arange(len(reads)), 0
    stamps = arrays["loop_stamp"]
    stamped = np.flatnonzero(np.isfinite(stamps) & np.isfinite(arrays["position"]).any(axis=1))
    if len(stamped) < 2:
        raise ValueError(
            f"{len(stamped)} readings stamped by the robot's loop; expected at least 2"
        )
    s = stamps[stamped]
    k = np.rint((s - s[0]) / dt)
    slope, origin = np.polyfit(k, s, 1) if k[-1] > 0 else (dt, s[0])
    times = origin + slope * np.arange(int(k[-1]) + 1)
    sent = np.searchsorted(arrays["write_time"], times[:-1], side="right") - 1
    return times, np.clip(sent, 0, len(reads) - 1), int(stamped[0])


def replay(robot, meta: dict, arrays: dict, plant: PlantMotors | None = None) -> np.ndarray:
    """(rows + 1, n) rad: the plant's true joint positions at the start of each row of the
    log's :func:`timeline` and after the last, the rows' commands written in order; on the
    robot's described motors, or on ``plant``'s.

    Raises:
        ValueError: the log is of other joints or another control period (:func:`check_log`),
            or a loop log with too few stamped readings (:func:`timeline`).
    """
    check_log(robot, meta)
    mode = meta["control_mode"]
    models = None if plant is None else [plant.apply(plant.robot.plant_model(mode))]
    backend = SimBackend(robot if plant is None else plant.robot, mode=mode, models=models)
    _, rows, first = timeline(arrays, robot.control_period)
    start = arrays["position"][first]
    q0 = np.where(np.isfinite(start), start, np.asarray(robot.home))
    backend.reset(q0)
    commands = arrays["command"][rows]
    out = np.empty((len(commands) + 1, robot.n_joints))
    out[0] = backend.true_position()[0]
    for k, command in enumerate(commands):
        backend.write(command[None])
        backend.advance()
        out[k + 1] = backend.true_position()[0]
    return out


def reading_errors(arrays: dict, simulated: np.ndarray, dt: float) -> np.ndarray:
    """(ticks, n) rad: each logged reading minus the replay's position at the row it was
    sampled (NaN where the reading dropped out or was sampled outside the replay).

    ``simulated`` is :func:`replay`'s, its row ``k`` the robot at ``times[k]`` of the log's
    :func:`timeline`. A reading's stamp (``position_stamp``; ``loop_stamp`` in a loop log) is
    placed among the rows by those times (on a wall clock a tick's period is the loop's, not
    exactly ``dt``) and taken to the nearest row."""
    times, margin = timeline(arrays, dt)[0], 0.0
    if "loop_stamp" in arrays:  # each stamp an update's time: the nearest row within dt / 2
        stamps = np.broadcast_to(arrays["loop_stamp"][:, None], arrays["position"].shape)
        margin = 0.5 * dt
    else:
        stamps = arrays["position_stamp"]
    inside = (stamps >= times[0] - margin) & (stamps <= times[-1] + margin)
    index = np.interp(stamps, times, np.arange(len(times), dtype=float))  # clamped at the ends
    index = np.where(inside, np.rint(index), np.nan)
    valid = np.isfinite(index) & (index >= 0) & (index < len(simulated))
    index = np.where(valid, index, 0).astype(np.int64)
    columns = np.arange(simulated.shape[1])[None, :]
    errors = arrays["position"] - simulated[index, columns]
    return np.where(valid & np.isfinite(arrays["position"]), errors, np.nan)
