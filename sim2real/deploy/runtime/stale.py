"""What went stale at a ``stale_sensor`` stop, and why: :class:`StaleStops`.

The runtime safe-stops an env with cause ``stale_sensor`` when one of its joints (or its IMU) has
had no fresh reading for longer than the robot's ``Robot.stale_limit``. A count of such stops
cannot tell a dead robot from a slow computer; at each such stop (and only then: nothing is
recorded or allocated on a tick without one) :meth:`StaleStops.record` joins

- the runtime's side: which joints, how long each had been without a fresh reading (s), what
  this tick's frame held for them (no reading, or one that was old);
- our own side in the window without a reading (wall clock only): how late this tick's read
  finished after its deadline (the wake-up's lateness plus the work before and in the read),
  the longest tick (wake-up lateness plus work) among those
  :class:`~sim2real.deploy.observe.long_ticks.LongTicks` kept in the window, the periods the
  loop missed (``Supervision.missed_in_last``);
- the reader's side: the backend's ``stale_context`` (:mod:`sim2real.deploy.core.stale`: the
  stream, samples arrived and refused since the last one taken, the newest one's age);

into one record with a one-line verdict, e.g. ``rt/lowstate: no fresh reading for 62 ms (robot
silent; our ticks on time)`` or ``joint_states: no fresh reading for 95 ms (our loop 82 ms late:
this computer, not the robot)``. Our loop is blamed when its delay in the window is at least
``BLAME_FRACTION`` of the time without a reading.
"""

from __future__ import annotations

import math

import numpy as np

from sim2real.deploy.core.stale import stale_context
from sim2real.deploy.observe import long_ticks as lt

#: Records kept per run; later stale stops are only counted (``StaleStops.dropped``).
MAX_RECORDS = 16
#: Our loop's delay in the window without a reading, as a fraction of that time, from which the
#: verdict blames this computer rather than the robot (our choice: half of it).
BLAME_FRACTION = 0.5


class StaleStops:
    """The records of a runtime's ``stale_sensor`` stops (module docstring).

    Args:
        runtime: The :class:`~sim2real.deploy.runtime.loop.Runtime` (its estimators, clock,
            stamps, long ticks and backend are read at a stop, not before).
        supervision: Its state machine, whose ``on_stale_stop`` becomes :meth:`record`.

    Attributes:
        records: One dict per stop and env, in order (at most ``MAX_RECORDS``): ``tick`` (the
            tick's index), ``t_s`` (s, the runtime's clock), ``env``, ``stream``, ``reader``,
            ``stale_limit_s``, ``without_reading_s`` (s, the longest of the stale sensors),
            ``joints`` (name -> s without a fresh reading, the stale joints), ``imu_s`` (s, the
            IMU's, where it was stale, else None), ``height_map_s`` (s, the elevation map's,
            likewise), ``camera_s`` (s, the camera's last fresh frame's age where it was past
            its own limit, :mod:`sim2real.deploy.runtime.camera`), ``this_tick`` (the frame's
            readings of those joints), ``our_side``, ``other_side`` (the backend's context) and ``verdict``.
        dropped: Stale stops past ``MAX_RECORDS``, counted only.
        on_record: None, or ``(record) -> None`` told every stop's record, those past
            ``MAX_RECORDS`` too (a soak counts each session's stops by what caused them,
            :mod:`sim2real.eval.soak.camera_verdict`); the record is built for it, not kept.
    """

    def __init__(self, runtime, supervision):
        self.runtime = runtime
        supervision.on_stale_stop = self.record
        self.records: list[dict] = []
        self.dropped = 0
        self.on_record = None

    def record(self, envs: np.ndarray) -> None:
        """Record the ``stale_sensor`` stop of each env of ``envs`` ((envs,) bool mask), made in
        this tick; called by the supervision at the stop (allocates: a stop is rare)."""
        for e in np.flatnonzero(envs):
            full = len(self.records) >= MAX_RECORDS
            record = None if full and self.on_record is None else self._record(int(e))
            if self.on_record is not None:
                self.on_record(record)
            if full:
                self.dropped += 1
            else:
                self.records.append(record)

    def _record(self, e: int) -> dict:
        rt = self.runtime
        limit = float(rt.robot.stale_limit)
        age = rt.estimator.time_since_fresh[e]
        stale = age > limit
        joints = {
            n: float(a) for n, a, s in zip(rt.robot.joint_names, age, stale, strict=True) if s
        }
        imu_s = None
        if rt.base_estimator is not None:
            imu = float(rt.base_estimator.time_since_fresh[e])
            imu_s = imu if imu > limit else None
        map_s, height_map = None, getattr(rt, "height_map", None)
        if height_map is not None and height_map.time_since_fresh[e] > limit:
            map_s = float(height_map.time_since_fresh[e])
        camera_s, cameras = None, getattr(rt, "cameras", None)
        # the stale cameras (several: each with its own limit), the oldest first
        stale_cams = [] if cameras is None else [c for c in cameras.inputs if c.stale[e]]
        stale_cams.sort(key=lambda c: -float(c.time_since_fresh[e]))
        if stale_cams:
            camera_s = float(stale_cams[0].time_since_fresh[e])
        without = max([*joints.values(), imu_s or 0.0, map_s or 0.0, camera_s or 0.0])
        this_tick = self._frame_view(e, stale)
        ours = self._our_side(without)
        other = stale_context(rt.backend, e)
        other["joints"] = {n: t for n, t in other.get("joints", {}).items() if n in joints}
        if camera_s is not None and not joints and imu_s is None and map_s is None:
            camera = stale_cams[0]  # the oldest; the others named after it
            kind = "colour" if camera.block.kind == "rgb" else "depth"
            stream = f"{kind} camera '{camera.block.camera}'"  # frozen or silent
            if len(stale_cams) > 1:
                stream += (
                    " (stale too: " + ", ".join(f"'{c.block.camera}'" for c in stale_cams[1:]) + ")"
                )
            other.update(stream=stream, other_side=camera.stale_phrase(e))
            if cameras is not None and len(cameras.inputs) > 1:
                other["camera"] = camera.block.camera  # which of the policy's cameras
            source = camera.source  # a plant camera says which of its faults came before
            if source is not None and hasattr(source, "recent"):
                done = other["camera_faults"] = source.recent(e, float(rt.time))
                other["other_side"] += (
                    f"; in the {done['window_s']:g} s before: {done['frozen']} frames frozen, "
                    f"{done['dropped']} dropped, {done['spiked']} late"
                )
        return {
            "tick": int(rt.ticks),
            "t_s": round(float(rt.time), 6),
            "env": e,
            "stream": other["stream"],
            "reader": other["reader"],
            "stale_limit_s": limit,
            "without_reading_s": _finite(without),
            "joints": {n: _finite(a) for n, a in joints.items()},
            "imu_s": _finite(imu_s),
            "height_map_s": _finite(map_s),
            "camera_s": _finite(camera_s),
            "this_tick": this_tick,
            "our_side": ours,
            "other_side": other,
            "verdict": verdict(other, this_tick, ours, without),
        }

    def _frame_view(self, e: int, stale: np.ndarray) -> dict:
        """This tick's frame for the stale joints of env ``e``: ``no_reading`` (names), and
        ``reading_age_s`` (name -> s from its sample to the frame's time) of those with one;
        ``refused_so_far`` (name -> readings the estimator refused as not newer since the
        start, a run's total: not only this window's)."""
        rt = self.runtime
        frame = getattr(rt.backend, "frame", None)
        names = [n for n, s in zip(rt.robot.joint_names, stale, strict=True) if s]
        index = np.flatnonzero(stale)
        if frame is None or not len(index):
            return {"no_reading": [], "reading_age_s": {}, "refused_so_far": {}}
        q, stamp = frame.position[e, index], frame.position_stamp[e, index]
        refused = rt.estimator.stale_per_joint[e, index]
        return {
            "no_reading": [n for n, v in zip(names, q, strict=True) if not np.isfinite(v)],
            "reading_age_s": {
                n: _finite(frame.time[e] - s)
                for n, v, s in zip(names, q, stamp, strict=True)
                if np.isfinite(v) and np.isfinite(s)
            },
            "refused_so_far": {n: int(c) for n, c in zip(names, refused, strict=True) if c},
        }

    def _our_side(self, without: float) -> dict:
        """Our loop in the ``without`` s before the stop (``window_ticks`` periods): lockstep
        (never late), or on the wall clock this tick's ``wake_late_s``, ``read_s`` and
        ``read_late_s`` (how late the read finished after its deadline), the
        ``missed_periods``, ``longest_tick_s`` (the longest tick kept in the window: lateness
        plus work; 0 where none was kept) and ``late_s``, the largest delay of these: the read's
        lateness, the longest tick's excess over a period, the missed periods' time (s)."""
        rt = self.runtime
        if not rt.clock.realtime:
            return {"realtime": False, "late_s": 0.0}
        dt, st, period = rt.dt, rt._stamps, rt._period
        window = max(1, math.ceil(without / dt)) if math.isfinite(without) else 1
        wake_late = max(int(period[lt.PREV_LATE]), 0) / 1e9
        read = (int(st[1]) - int(st[0])) / 1e9
        woke = int(period[lt.PREV_WAKE])
        read_late = wake_late + ((int(st[1]) - woke) / 1e9 if woke > 0 else read)
        table = rt.long_ticks.table
        rows = table[(table[:, lt.TOTAL] > 0) & (table[:, lt.TICK] > rt.ticks - window)]
        longest = float(rows[:, lt.TOTAL].max()) / 1e9 if len(rows) else 0.0
        missed = rt.supervision.missed_in_last(window)
        late = max(read_late, longest - dt, missed * dt, 0.0)
        return {
            "realtime": True,
            "window_ticks": window,
            "wake_late_s": _finite(wake_late),
            "read_s": _finite(read),
            "read_late_s": _finite(read_late),
            "missed_periods": missed,
            "longest_tick_s": _finite(longest),
            "late_s": _finite(late),
        }


def verdict(other: dict, this_tick: dict, ours: dict, without: float) -> str:
    """The one-line verdict of a stale stop: ``STREAM: no fresh reading for N ms (OTHER SIDE;
    OUR SIDE)``, our side first and to blame (``our loop N ms late: this computer, not the
    robot``) where its delay ``ours["late_s"]`` is at least ``BLAME_FRACTION`` of ``without``
    (s); the other side is the reader's phrase, or the frame's where the reader has none, and
    the newest sample's age by its source stamp where the reader knows it."""
    if not without:  # a stop made from outside the tick's stale check (a test, a caller)
        return f"{other['stream']}: no sensor past the stale limit at the stop"
    head = f"{other['stream']}: " + (
        f"no fresh reading for {_ms(without)}" if math.isfinite(without) else "no reading yet"
    )
    theirs = other.get("other_side") or _frame_phrase(this_tick)
    if other.get("other_side") and this_tick["reading_age_s"]:
        theirs += "; " + _frame_phrase(this_tick)
    if other.get("newest_sample_age_s") is not None:
        theirs += f", newest sample {_ms(other['newest_sample_age_s'])} old"
    if ours["realtime"] and ours["late_s"] >= BLAME_FRACTION * without:
        blame = f"our loop {_ms(ours['late_s'])} late: this computer, not the robot"
        return f"{head} ({blame}" + (f"; {theirs})" if other.get("arrived") else ")")
    mine = "our ticks on time" + ("" if ours["realtime"] else ", lockstep")
    return f"{head} ({theirs}; {mine})" if theirs else f"{head} ({mine})"


def _frame_phrase(this_tick: dict) -> str:
    """What this tick's frame held for the stale joints: no reading, or readings N ms old (a
    repeated stamp the estimator refused, or a late one)."""
    ages = this_tick["reading_age_s"]
    if not ages:
        return "no reading arrived"
    return f"readings arriving but {_ms(max(ages.values()))} old (repeated or late)"


def _ms(seconds: float) -> str:
    """``62 ms`` from seconds (finite)."""
    return f"{1e3 * seconds:.0f} ms"


def _finite(value: float | None) -> float | None:
    """``value`` (s) as a float to the microsecond, None where None or not finite (JSON has no
    inf)."""
    return round(float(value), 6) if value is not None and math.isfinite(value) else None
