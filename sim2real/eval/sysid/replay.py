"""A logged run's commands replayed open-loop through the plant: what the plant's joints do under
exactly the commands the robot was sent (:func:`replay`), and how far that is from what the robot
read (:func:`reading_errors`).

The replay starts at rest at the log's first readings and writes the logged command of every
tick; it compares each logged reading with the plant's true joint position at the tick the
reading was sampled (its stamp), so the log's sensor latency is no error of the motors.
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


def replay(robot, meta: dict, arrays: dict, plant: PlantMotors | None = None) -> np.ndarray:
    """(ticks + 1, n) rad: the plant's true joint positions at the start and after each logged
    tick, the log's commands written in order; on the robot's described motors, or on
    ``plant``'s.

    Raises:
        ValueError: the log is of other joints or another control period (:func:`check_log`).
    """
    check_log(robot, meta)
    mode = meta["control_mode"]
    models = None if plant is None else [plant.apply(plant.robot.plant_model(mode))]
    backend = SimBackend(robot if plant is None else plant.robot, mode=mode, models=models)
    start = arrays["position"][0]
    q0 = np.where(np.isfinite(start), start, np.asarray(robot.home))
    backend.reset(q0)
    commands = arrays["command"]
    out = np.empty((len(commands) + 1, robot.n_joints))
    out[0] = backend.true_position()[0]
    for k, command in enumerate(commands):
        backend.write(command[None])
        backend.advance()
        out[k + 1] = backend.true_position()[0]
    return out


def reading_errors(arrays: dict, simulated: np.ndarray, dt: float) -> np.ndarray:
    """(ticks, n) rad: each logged reading minus the replay's position at the tick it was
    sampled (NaN where the reading dropped out or was sampled outside the replay).

    The replay's row ``k`` is the robot when tick ``k`` read (before its command); a reading's
    stamp is placed among the ticks by the backend's clock of each tick's read (``read_time``):
    on a wall clock the periods are the loop's, not exactly ``dt``."""
    stamps = arrays["position_stamp"]
    reads = arrays["read_time"]
    ticks = np.arange(len(reads), dtype=float)
    inside = (stamps >= reads[0]) & (stamps <= reads[-1] + dt)
    index = np.interp(stamps, reads, ticks, right=np.nan)  # past the last read: one dt on
    index = np.where(stamps > reads[-1], len(reads) - 1 + (stamps - reads[-1]) / dt, index)
    index = np.where(inside, np.rint(index), np.nan)
    valid = np.isfinite(index) & (index >= 0) & (index < len(simulated))
    index = np.where(valid, index, 0).astype(np.int64)
    columns = np.arange(simulated.shape[1])[None, :]
    errors = arrays["position"] - simulated[index, columns]
    return np.where(valid & np.isfinite(arrays["position"]), errors, np.nan)
