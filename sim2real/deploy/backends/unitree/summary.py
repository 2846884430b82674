"""What a :class:`~sim2real.deploy.backends.unitree.backend.UnitreeBackend` tells the run's report:
the DDS figures of the whole run (:func:`bus_summary`) and what ``rt/lowstate``'s reader saw at a
stale-sensor stop (:func:`stale_context`). Both read the backend's counters; neither is called
per tick.
"""

from __future__ import annotations

import time

from sim2real.deploy.backends.unitree.family import TOPIC_LOWSTATE
from sim2real.deploy.core.stale import arrivals_phrase, context

#: The kinds of refused states a stale window counts (``DROPOUT_KINDS`` but ``lost``, which is
#: only known once a later state is taken).
REFUSED_KINDS = ("bad_crc", "malformed", "stale")


def bus_summary(b) -> dict:
    """Figures for the run's report: family, interface, domain, ``mode_machine``, states taken
    and their rate, dropouts by kind and their fraction of the states the robot sent, packets
    each motor lost, commands sent, the cost of a read and a write, the newest state's age at a
    read (us percentiles), latched driver errors, the bring-up's time and the hold at home
    before the runtime's first command (s); ``b`` the backend."""
    elapsed = time.monotonic() - (b._opened_at or b._t0)
    expected = b.received + b.dropouts["lost"]
    return {
        "transport": "dds",
        "family": b.family.name,
        "interface": b.interface,
        "domain_id": b.domain_id,
        "mode_machine": b.mode_machine,
        "reads": b.reads,
        "lowstate_received": b.received,
        "lowstate_rate_hz": b.received / elapsed if elapsed > 0 else 0.0,
        "bringup_s": b.bringup_s,
        "held_at_home_s": b.held_at_home_s,
        "lowcmd_sent": b.sent,
        "lowcmd_resent": b.resent,
        "lowcmd_rate_hz": None if b.resend_period is None else 1.0 / b.resend_period,
        "dropouts": dict(b.dropouts),
        "lowstate_unchecked": b.unchecked if b.lowstate_unchecked else None,
        "dropout_fraction": sum(b.dropouts.values()) / expected if expected else 0.0,
        "motor_lost": {
            f"{int(b.slots[j])} ({b.names[j]})": int(n) for j, n in enumerate(b.motor_lost) if n
        },
        "read_us": b.read_cost.summary(),
        "write_us": b.write_cost.summary(),
        "state_age_us": b.state_age.summary(),
        "driver_errors": [
            b.describe_drive_error(j, int(e)) for j, e in enumerate(b.latched_errors) if e
        ],
    }


def stale_context(b) -> dict:
    """What ``rt/lowstate``'s reader saw since the last read that took a state
    (:mod:`sim2real.deploy.core.stale`'s keys): the states that arrived since and those refused
    by kind (``REFUSED_KINDS``), the newest state's age by its source timestamp (and the taken
    one's, ``taken_sample_age_s``), s since a state was taken; ``joints``: the motors that lost
    packets this run. ``other_side``: ``robot silent`` when nothing arrived, the refusals when
    something did, or, where a state was taken within the stale limit (a joint's own reading
    missing), the motors' lost packets."""
    now_ns, now = time.time_ns(), time.monotonic() - b._t0
    at = b.at_taken
    arrived = b.received - at["received"]
    refused = {k: b.dropouts[k] - at[k] for k in REFUSED_KINDS}
    joints = {
        b.names[j]: f"motor {int(b.slots[j])}: {int(n)} packets lost this run"
        for j, n in enumerate(b.motor_lost)
        if n
    }
    since = now - b._last_fresh
    other = arrivals_phrase(arrived, refused, "robot silent")
    if since <= b.robot.stale_limit:  # states taken: a joint's own reading lost
        other = f"states arriving (one taken {1e3 * since:.0f} ms ago)" + (
            f", motors losing packets ({len(joints)})" if joints else ""
        )
    where = f"{b.interface or 'default interface'}, domain {b.domain_id}"
    return context(
        "unitree",
        TOPIC_LOWSTATE,
        f"{TOPIC_LOWSTATE} over DDS ({b.family.name}, {where})",
        arrived=arrived,
        refused=refused,
        newest_sample_age_s=(now_ns - b.newest_stamp_ns) / 1e9 if b.newest_stamp_ns else None,
        last_accepted_s=since,
        joints=joints,
        other_side=other,
        taken_sample_age_s=(now_ns - b.taken_stamp_ns) / 1e9 if b.taken_stamp_ns else None,
        lowstate_received=b.received,
    )
