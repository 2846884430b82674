"""A run's commands and encoder readings, every tick: the log an identification of the robot's
motors is fitted to (``sysid``, :mod:`sim2real.eval.sysid`).

``deploy-run --record-commands run.npz`` keeps, after every control tick of env 0, the command
the runtime wrote (units of the control mode) and the encoder readings the backend holds then
(rad, NaN where a reading dropped) with the times they were sampled (s), on any backend: the
MuJoCo plant, an emulator, the real robot. Rows are kept in preallocated blocks (nothing is
allocated per tick but one block every ``BLOCK`` ticks) and written once, atomically, when the
run ends: ``t`` (ticks,) s, ``command``, ``position`` and ``position_stamp`` (ticks, n) and
``read_time`` (ticks,) s, the backend's clock of the frame each tick read (the clock of the
stamps: the plant's time, or a real backend's monotonic clock) and ``meta`` (JSON: robot, its
description hash, control mode and period, backend, joint names). A backend whose robot runs its
own fixed-rate update loop (``--backend ros2``: its ``loop_times``) adds ``loop_stamp``
(ticks,) s, when that loop sampled the state the tick read (NaN: no new state), and
``write_time`` (ticks,) s, when the tick's command was sent, on the same clock; ``meta`` then
has ``"robot_loop": true`` (the replay steps on the robot's updates).
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np

from sim2real.robots.errors import Sim2RealError
from sim2real.robots.files import atomic_write

#: Rows per preallocated block.
BLOCK = 4096


class CommandLogError(Sim2RealError, ValueError):
    """A command log that cannot be read (the message names the file and what is wrong)."""


class CommandLog:
    """Records env 0's commands and encoder readings after every tick (module docstring).

    Args:
        path: The ``.npz`` file written at :meth:`close`.
        robot: The robot (its name, hash and joints go into ``meta``).
        mode: The control mode of the commands.
        backend: The backend's name (``sim``, ``feetech``, ``unitree``, ...).
    """

    def __init__(self, path, robot, mode: str, backend: str):
        self.path = Path(path)
        self.meta = {
            "robot": robot.name,
            "description_hash": robot.description_hash,
            "control_mode": mode,
            "control_period": robot.control_period,
            "backend": backend,
            "joint_names": list(robot.joint_names),
        }
        self.n = robot.n_joints
        self.rows = 0
        self._blocks: list[dict[str, np.ndarray]] = []

    def _block(self) -> dict[str, np.ndarray]:
        i = self.rows % BLOCK
        if i == 0:
            self._blocks.append(
                {
                    "t": np.zeros(BLOCK),
                    "read_time": np.zeros(BLOCK),
                    "command": np.zeros((BLOCK, self.n)),
                    "position": np.zeros((BLOCK, self.n)),
                    "position_stamp": np.zeros((BLOCK, self.n)),
                    "loop_stamp": np.zeros(BLOCK),
                    "write_time": np.zeros(BLOCK),
                }
            )
        return self._blocks[-1]

    def record(self, runtime) -> None:
        """After a tick of ``runtime``: its time, env 0's command and the backend's readings."""
        block, i = self._block(), self.rows % BLOCK
        frame = runtime.backend.frame
        block["t"][i] = runtime.time
        block["read_time"][i] = runtime.read_time[0]
        block["command"][i] = runtime.command[0]
        block["position"][i] = frame.position[0]
        block["position_stamp"][i] = frame.position_stamp[0]
        loop = getattr(runtime.backend, "loop_times", None)
        if loop is not None:
            self.meta["robot_loop"] = True
            block["loop_stamp"][i], block["write_time"][i] = loop
        self.rows += 1

    def arrays(self) -> dict[str, np.ndarray]:
        """The recorded rows as one array per field (copies)."""
        out = {}
        keys = ["t", "read_time", "command", "position", "position_stamp"]
        keys += ["loop_stamp", "write_time"] if self.meta.get("robot_loop") else []
        for key in keys:
            parts = [b[key] for b in self._blocks]
            out[key] = np.concatenate(parts)[: self.rows] if parts else np.zeros((0,))
        return out

    def close(self) -> Path:
        """Write the log (atomically) and return its path."""
        buffer = io.BytesIO()
        np.savez(buffer, meta=np.array(json.dumps(self.meta)), **self.arrays())
        return atomic_write(self.path, buffer.getvalue())


def read_command_log(path) -> tuple[dict, dict[str, np.ndarray]]:
    """``(meta, arrays)`` of a command log (:class:`CommandLog`).

    Raises:
        CommandLogError: a missing or unreadable file, or one without the fields of a log.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        msg = f"{path}: not a command log (deploy-run --record-commands): {exc}"
        raise CommandLogError(msg) from None
    missing = [k for k in ("meta", "t", "command", "position", "position_stamp") if k not in arrays]
    if missing:
        raise CommandLogError(f"{path}: a command log needs {', '.join(missing)}")
    meta = json.loads(str(arrays.pop("meta")))
    if len(arrays["t"]) < 2:
        raise CommandLogError(f"{path}: {len(arrays['t'])} ticks recorded; expected at least 2")
    return meta, arrays
