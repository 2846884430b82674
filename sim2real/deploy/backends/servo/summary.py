"""What a servo bus (:class:`~sim2real.deploy.backends.servo.servo_bus.ServoBusBackend`) tells the
run's report: the bus figures of the whole run (:func:`bus_summary`) and what its SYNC READ saw of
each servo at a stale-sensor stop (:func:`stale_context`). Both read the backend's counters;
neither is called per tick.
"""

from __future__ import annotations

import time

from sim2real.deploy.core.stale import context


def bus_summary(b) -> dict:
    """Bus figures for the run's report: port, baud rate, SYNC READs sent, dropouts by kind and
    per read slot, the cost of a read and a write (us percentiles), latched errors; ``b`` the
    backend."""
    slots = b.reads * b.n
    return {
        "protocol": b.protocol,
        "port": b.port_name,
        "baudrate": b.baudrate,
        "servo_ids": list(b.ids),
        "sync_reads": b.reads,
        "dropouts": dict(b.dropouts),
        "dropout_fraction": sum(b.dropouts.values()) / slots if slots else 0.0,
        "read_us": b.read_cost.summary(),
        "write_us": b.write_cost.summary(),
        "torque_checks": b.torque_checks,
        "torque_check_us": b.check_cost.summary(),
        "servo_errors": [
            b.describe_drive_error(b.ids.index(sid), bits)
            for sid, bits in sorted(b.latched_errors.items())
        ],
    }


def stale_context(b) -> dict:
    """What the SYNC READ saw of each servo (:mod:`sim2real.deploy.core.stale`'s keys): per joint
    whose servo missed its last replies, its ID, the reads in a row without a reply and s since
    its last one; the corrupt replies since a read every servo answered (``refused``: the SDK
    does not say whose); ``other_side`` names the silent servos (``servo IDs 3, 5 silent``), None
    when every servo answered the last read; ``last_read_s``, the last SYNC READ's duration
    (s)."""
    now = time.monotonic() - b._t0
    silent = [j for j in range(b.n) if b._unanswered[j]]
    joints = {
        b.names[j]: f"servo ID {b.ids[j]}: {int(b._unanswered[j])} reads without a reply, the "
        f"last {now - b._replied_at[j]:.3f} s ago"
        for j in silent
    }
    ids = ", ".join(str(b.ids[j]) for j in silent)
    other = f"servo ID{'s' if len(silent) > 1 else ''} {ids} silent" if silent else None
    if other and b._corrupt_run:
        other += f" ({b._corrupt_run} corrupt replies meanwhile)"
    return context(
        b.protocol,
        "SYNC READ",
        f"{b.protocol} bus {b.port_name} at {b.baudrate} bit/s, SYNC READ of servo IDs "
        f"{', '.join(map(str, b.ids))}",
        refused={"corrupt": b._corrupt_run},
        joints=joints,
        other_side=other,
        dropouts=dict(b.dropouts),
        last_read_s=b._read_ns / 1e9,
    )
