"""The servo bus: one SYNC READ + one SYNC WRITE per tick through the vendor SDK, against the
wire-protocol emulator in its own process (``python -m sim2real.deploy.backends.emulator``).

Per robot (so101: 6 Feetech STS3215 on ``scservo_sdk``; arm3_xm430: 3 Dynamixel XM430 on
``dynamixel_sdk``, Protocol 2.0), at 1 Mbaud, back to back with no sleep: the cost of a bus tick
(``read()`` + ``write()`` of the backend) and the tick rate the bus sustains (1 / mean). Beside it,
the emulator's timing model for the same exchange (no host or emulator cost): the bytes on the
wire at 10 bits per byte (start, 8 data, stop) plus each reply's Return_Delay_Time (0 after the
backend's ``open()``)::

    Feetech    SYNC READ  8 + n  bytes, each reply 6 + L;  SYNC WRITE 8 + n (1 + W)
    Dynamixel  SYNC READ 14 + n  bytes, each reply 11 + L; SYNC WRITE 14 + n (1 + W)

(``L`` the read block, ``W`` the goal register, in bytes; packet layouts from the Feetech
SCServo protocol and the ROBOTIS e-Manual, Protocol 2.0.)
"""

from __future__ import annotations

import gc
import time

import numpy as np

from bench.common import histogram, summary
from sim2real.deploy.harness.servo_hil import start_emulator, stop_emulator

CASES = (("so101", "feetech"), ("arm3_xm430", "dynamixel"))
BAUDRATE = 1_000_000


def wire_model_us(protocol: str, n: int, block: int, goal: int, baudrate: int) -> float:
    """us on the wire for one SYNC READ of ``n`` servos (``block`` bytes each) and one SYNC
    WRITE (``goal`` bytes each), at ``baudrate`` with 10 bits per byte (module docstring)."""
    if protocol == "feetech":
        nbytes = (8 + n) + n * (6 + block) + (8 + n * (1 + goal))
    else:
        nbytes = (14 + n) + n * (11 + block) + (14 + n * (1 + goal))
    return nbytes * 10.0 / baudrate * 1e6


def bench_bus(robot_name: str, protocol: str, ticks: int) -> dict:
    """Per-tick bus cost (read + write) of ``ticks`` back-to-back ticks; see the module
    docstring. Raises ImportError without the servo extra (``pip install '.[servo]'``)."""
    from sim2real.robots import load_robot

    if protocol == "feetech":
        from sim2real.deploy.backends.servo.feetech import FeetechBackend as Backend
    else:
        from sim2real.deploy.backends.servo.dynamixel import DynamixelBackend as Backend
    robot = load_robot(robot_name)
    proc, port = start_emulator(robot_name, protocol, BAUDRATE)
    if port is None:
        stop_emulator(proc)
        raise RuntimeError(f"the {protocol} emulator for {robot_name} did not start")
    try:
        with Backend(robot, port, baudrate=BAUDRATE) as bus:
            goal = np.asarray(robot.home, dtype=np.float64)[None]
            for _ in range(50):  # warm-up
                bus.read()
                bus.write(goal)
            out = np.empty(ticks, dtype=np.int64)
            gc.collect()
            gc.disable()
            try:
                for i in range(ticks):
                    t = time.perf_counter_ns()
                    bus.read()
                    bus.write(goal)
                    out[i] = time.perf_counter_ns() - t
            finally:
                gc.enable()
            dropouts = dict(bus.dropouts)
            block, goal_size, n = bus.block_length, bus.goal_register.size, bus.n
    finally:
        stop_emulator(proc)
    row = {"robot": robot_name, "protocol": protocol, "servos": n, "baudrate": BAUDRATE}
    row.update(summary(histogram(out)))
    row["sustained_hz"] = 1e9 / float(out.mean())
    row["wire_model_us"] = wire_model_us(protocol, n, block, goal_size, BAUDRATE)
    row["read_block_bytes"], row["goal_bytes"] = block, goal_size
    row["dropouts"] = dropouts
    return row


def run(ticks: int) -> dict:
    """The ``bus`` section of results.json: one row per case of :data:`CASES`."""
    try:
        import dynamixel_sdk  # noqa: F401
        import scservo_sdk  # noqa: F401
    except ImportError as err:
        return {"skipped": f"servo SDKs missing ({err}); pip install '.[servo]'", "rows": []}
    return {"ticks": ticks, "rows": [bench_bus(r, p, ticks) for r, p in CASES]}
