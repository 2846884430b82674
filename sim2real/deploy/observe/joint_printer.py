"""``deploy-run --print-joints HZ``: the seed's "print joint states", one line per print.

A user checks with it that an action moves the right joint in the right direction: every
``1 / HZ`` s of the clock that runs (simulated time with the lockstep clock, wall time with the
wall clock) it prints, per env, the state machine's mode and per joint the estimated position and
velocity (``rt.state``), the command the runtime wrote to the backend (``rt.command``) and the
winding temperature::

    joints t=1.250s RUNNING | shoulder q=+0.123 dq=-0.456 cmd=+0.130 T=31.2 | elbow ...

Units: q rad, dq rad/s, cmd in the units of the control mode (position rad, velocity rad/s,
torque N m), T degC. A header line names them once, before the first print.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

import numpy as np

CMD_UNITS = {"position": "rad", "velocity": "rad/s", "torque": "N m"}


class JointPrinter:
    """Print joint states at ``hz`` prints per second; call it after every tick.

    Reads only the runtime's public attributes (``time``, ``mode``, ``state``, ``command``,
    ``clock``): the run is the same with or without it.

    Args:
        joint_names: Joint names, in the robot's order (n,).
        hz: Prints per second (> 0) of the clock that runs: simulated time with a lockstep
            clock, wall time with a wall clock. At most one print per tick.
        control_mode: ``position``, ``velocity`` or ``torque`` (the unit of ``cmd``).
        stream: Where the lines go (default ``sys.stdout``).

    Raises:
        ValueError: ``hz`` not a finite number > 0, or an unknown ``control_mode``.
    """

    def __init__(
        self,
        joint_names: list[str] | tuple[str, ...],
        hz: float,
        control_mode: str,
        stream: TextIO | None = None,
    ):
        if not (np.isfinite(hz) and hz > 0):
            raise ValueError(f"--print-joints: expected a rate in Hz > 0, got {hz}")
        if control_mode not in CMD_UNITS:
            raise ValueError(
                f"control_mode: expected one of {tuple(CMD_UNITS)}, got {control_mode}"
            )
        self.names = list(joint_names)
        self.period = 1.0 / float(hz)
        self.control_mode = control_mode
        self.stream = stream if stream is not None else sys.stdout
        self.lines = 0
        self._next: float | None = None

    def header(self) -> str:
        return (
            f"print-joints: every {self.period:.3g} s; q rad, dq rad/s, cmd "
            f"{CMD_UNITS[self.control_mode]} ({self.control_mode} control), T winding degC"
        )

    def format(self, rt, e: int = 0) -> str:
        """One line for env ``e`` of runtime ``rt`` (module docstring)."""
        from sim2real.deploy.core.modes import Mode

        q, dq = rt.state.q[e], rt.state.dq[e]
        cmd, temp = rt.command[e], rt.state.winding_temperature[e]
        env = f" env={e}" if rt.envs > 1 else ""
        joints = " | ".join(
            f"{name} q={q[j]:+.3f} dq={dq[j]:+.3f} cmd={cmd[j]:+.3f} T={temp[j]:.1f}"
            for j, name in enumerate(self.names)
        )
        return f"joints t={rt.time:.3f}s{env} {Mode(int(rt.mode[e])).name} | {joints}"

    def __call__(self, rt) -> None:
        """Print if a period of the running clock has passed since the last print."""
        realtime = bool(getattr(rt.clock, "realtime", False))
        now = time.perf_counter() if realtime else rt.time
        if self._next is None:
            print(self.header(), file=self.stream)
            self._next = now
        if now + 1e-9 < self._next:
            return
        for e in range(rt.envs):
            print(self.format(rt, e), file=self.stream, flush=realtime)
            self.lines += 1
        # the next print time: the next multiple of the period (no burst after a stall)
        self._next += self.period * max(1, int((now + 1e-9 - self._next) // self.period) + 1)
