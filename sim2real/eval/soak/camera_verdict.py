"""A camera policy's soak verdict (:class:`CameraVerdict`): which camera faults each session
survived, which stopped it safely and whether it ran again, and which camera fault each failure
followed.

A camera whose frames freeze, fall silent or come late is stale like any sensor: the runtime
safe-stops the env (``stale_sensor``) and, at rest, latches it (FAULTED) until the operator
resets it, as it does for a silent encoder or IMU (:mod:`sim2real.deploy.runtime.camera`). The
soak draws its encoder and IMU faults within the stale budget (every one survivable), so a latch
there has no injected cause and fails the session. Its camera faults are drawn past it (a frozen
spell of 5-30 frames outlasts the camera's stale limit): a stop is the response they test. A
latch that followed a stale-camera stop with an injected camera fault in the second before it is
therefore *stopped safely* (the latch dict's ``injected``: ``camera: <fault>``), not a failure;
``no_latched_fault`` (:func:`sim2real.eval.report.build.session_checks`) fails only on latches
without one. After the operator's reset (``operator_reset`` s) the session records when the env
ran again (``running_again_s``).

Every stale-camera stop is counted by the faults it followed (``frozen``, ``dropped``, ``late``,
joined by ``+``, or ``none``) and the first ``STOP_SAMPLE`` of each session kept with the
runtime's verdict (the runtime keeps ``MAX_RECORDS`` per batch; :attr:`StaleStops.on_record`
tells this verdict about every one). A failure (a hard-limit violation's onset, a missed goal, a
fall, a latch without an injected cause) is counted by the per-frame camera faults of the
``WINDOW`` s before the supervision step that saw it (a missed goal: of the goal's last period,
or ``camera stop after <fault>`` when a stale-camera stop interrupted the goal), the first
``FAILURE_SAMPLE`` kept. A stop counts for its first fault (frozen, dropped, late). The
session-wide faults (a covered lens, a knocked mount, a lighting change) act throughout and
are listed once. A fault of the soak's own schedule whose response counts a stale-camera stop
in its window says so (its event's ``camera_stop``). Hooks: ``SessionBatch`` makes it and calls
:meth:`~CameraVerdict.step` each supervision step; the session's checkpoint holds its state.
"""

from __future__ import annotations

import math

import numpy as np

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.core.stateful import env_list, read_records, records_json
from sim2real.eval.soak.session import ARM_LEAD
from sim2real.eval.world.fault_schedule import FAULT_SETTLE

#: s of camera faults before a failure that it followed (the plant camera's ``recent`` window).
WINDOW = 1.0
#: Stale-camera stops kept per session with their verdict (all are counted).
STOP_SAMPLE = 16
#: Failures kept per session with the camera faults they followed (all are counted).
FAILURE_SAMPLE = 32
#: s within which a stale-camera stop told at its tick is the safe stop a supervision step
#: sees (its period is 0.1 s: ``sim2real.eval.soak.batch.SUPERVISE_PERIOD``).
STEP_S = 0.15
#: Stale-camera stops remembered per session to tell which of the soak's own faults a camera
#: stop was judged with (their windows last seconds; our choice).
RECENT_STOPS = 8
#: The failures a session's camera verdict attributes.
FAILURES = ("hard_violation", "missed_goal", "fall", "latched")
#: The plant camera's per-frame fault counts (``PlantCamera.recent``) -> their name here.
FRAME_FAULTS = (("frozen", "frozen"), ("dropped", "dropped"), ("spiked", "late"))


def fault_label(recent: dict | None) -> str:
    """The per-frame camera faults of a ``PlantCamera.recent`` window as one label:
    ``frozen``, ``dropped``, ``late`` joined by ``+`` in that order, ``none`` without; a
    window of several cameras (``by_camera``): each faulted camera's name and label, joined by
    ``; `` (``wrist frozen; front dropped``)."""
    if not recent:
        return "none"
    if "by_camera" in recent:
        labels = ((name, fault_label(r)) for name, r in recent["by_camera"].items())
        return "; ".join(f"{name} {label}" for name, label in labels if label != "none") or "none"
    kinds = [name for key, name in FRAME_FAULTS if recent.get(key)]
    return "+".join(kinds) or "none"


def fault_kind(label: str) -> str:
    """A stop's first per-frame fault (``frozen``, ``dropped``, ``late``) of its label, the
    camera's name (several cameras) dropped."""
    return label.rsplit(" ", 1)[-1].split("+")[0]


def throughout(faults: dict, kind: str) -> list[str]:
    """The session-wide camera faults of a drawn ``CameraFaults`` dict, in words (a colour
    camera's lighting; a depth camera ignores it): ``[]`` without."""
    out = []
    if faults.get("occlusion", 0.0) > 0:
        out.append(f"lens {100 * faults['occlusion']:.1f} % covered")
    knocked = float(np.degrees(np.abs(faults.get("extrinsic", (0, 0, 0)))).max())
    if knocked > 0:
        out.append(f"mount knocked {knocked:.2f} deg")
    if kind == "rgb" and faults.get("lighting", 1.0) != 1.0:
        out.append(f"light x{faults['lighting']:.2f}")
    return out


def _fresh() -> dict:
    return {
        "stops": {"count": 0, "by_fault": {}, "sample": [], "last_t_s": None, "last": "none"},
        "failures": {"counts": {f: {} for f in FAILURES}, "sample": [], "dropped": 0},
        "seen": {"hard": 0, "missed": 0, "falls": 0, "latches": 0, "stops": 0, "events": 0},
        "recent_stops": [],
        "hard_before": False,
        "last_stop": None,
    }


class CameraVerdict:
    """Per session of a camera policy's batch: its stale-camera stops and its failures by the
    camera faults they followed (module docstring).

    Args:
        batch: The :class:`~sim2real.eval.soak.batch.SessionBatch` (its runtime ``rt``, whose
            ``cameras`` stage and ``stale_stops`` are read; its plant camera ``camera``, whose
            ``recent`` faults are; its ``violations``, ``task``, ``sessions``).
    """

    def __init__(self, batch):
        self.batch, self.source = batch, batch.camera
        #: several cameras: the plant's by name (their faults are told apart), else None
        self.sources = getattr(batch.camera, "sources", None)
        self.state = [_fresh() for _ in range(batch.rt.envs)]
        batch.rt.stale_stops.on_record = self.stale_stop

    @classmethod
    def of_batch(cls, batch) -> CameraVerdict | None:
        """The verdict of a batch whose policy reads a plant camera; None without one."""
        if batch.camera is None or getattr(batch.rt, "cameras", None) is None:
            return None
        return cls(batch)

    # ------------------------------------------------------------------ events
    def _recent(self, e: int, t: float, window: float = WINDOW) -> dict:
        """The camera's ``recent`` faults; several cameras: their counts summed, and each
        camera's under ``by_camera``."""
        if self.sources is None:
            return self.source.recent(e, t, window)
        per = {name: src.recent(e, t, window) for name, src in self.sources.items()}
        counts = {k: sum(r[k] for r in per.values()) for k in ("dropped", "spiked", "frozen")}
        return {"window_s": window, **counts, "by_camera": per}

    def stale_stop(self, record: dict) -> None:
        """A ``stale_sensor`` stop's record (``StaleStops.on_record``): counted when the camera
        alone was stale, by the faults it followed; the first ``STOP_SAMPLE`` kept."""
        if record["camera_s"] is None or record["joints"] or record["imu_s"] is not None:
            return
        if record["height_map_s"] is not None:
            return
        e = record["env"]
        followed = record["other_side"].get("camera_faults")
        label = fault_label(followed)
        camera = record["other_side"].get("camera")  # several cameras: the stale one
        if camera is not None and label != "none":
            label = f"{camera} {label}"
        stops = self.state[e]["stops"]
        stops["count"] += 1
        stops["by_fault"][label] = stops["by_fault"].get(label, 0) + 1
        stops["last_t_s"], stops["last"] = record["t_s"], label
        recent = self.state[e]["recent_stops"]
        recent[:] = [*recent[-(RECENT_STOPS - 1) :], [record["t_s"], label]]
        if len(stops["sample"]) < STOP_SAMPLE:
            stops["sample"].append(
                {
                    "t_s": record["t_s"],
                    "camera_s": record["camera_s"],
                    "followed": followed,
                    "verdict": record["verdict"],
                }
            )

    def _failure(self, e: int, failure: str, t: float, recent: dict, stop=False) -> str:
        label = fault_label(recent)
        if stop:  # the goal's period held a stale-camera stop: the miss followed it
            label = f"camera stop after {self.state[e]['stops']['last']}"
        f = self.state[e]["failures"]
        f["counts"][failure][label] = f["counts"][failure].get(label, 0) + 1
        if len(f["sample"]) < FAILURE_SAMPLE:
            frames = {name: int(recent.get(key, 0)) for key, name in FRAME_FAULTS}
            f["sample"].append({"failure": failure, "t_s": t, "camera": label, "frames": frames})
        else:
            f["dropped"] += 1
        return label

    def step(self, rt, t: float) -> None:
        """One supervision step at ``t`` s (after the batch's latch and reset bookkeeping):
        new safe stops, latches, hard-limit onsets, missed goals and falls of every session."""
        b = self.batch
        hard = b.violations.counts["hard_limit"]
        goals = getattr(b.task, "scheduler", None)
        tracker = getattr(b.task, "tracker", None)
        for s in b.sessions:
            e, st = s.e, self.state[s.e]
            seen = st["seen"]
            stops = int(rt.counters.safe_stops[e])
            if stops > seen["stops"]:  # a camera stop told at its tick, else this step's window
                last = st["stops"]["last_t_s"]
                if last is not None and t - last < STEP_S:
                    st["last_stop"] = {"t_s": last, "camera": st["stops"]["last"]}
                else:
                    st["last_stop"] = {"t_s": t, "camera": None, "before": self._recent(e, t)}
                seen["stops"] = stops
            for latch in s.latches[seen["latches"] :]:
                self._latch(e, latch, t)
            seen["latches"] = len(s.latches)
            if s.latches and s.latches[-1].get("injected") and s.latches[-1]["reset_s"]:
                latch = s.latches[-1]
                if "running_again_s" not in latch and int(rt.mode[e]) == RUNNING:
                    latch["running_again_s"] = round(t, 6)
            for ev in s.fault_events[seen["events"] :]:  # the soak's own faults, judged
                self._fault_event(st, ev)
            seen["events"] = len(s.fault_events)
            now = int(hard[e])
            if now > seen["hard"] and not st["hard_before"]:
                self._failure(e, "hard_violation", t, self._recent(e, t))
            st["hard_before"], seen["hard"] = now > seen["hard"], now
            if goals is not None:
                missed = goals.missed[e]
                for rec in missed[min(seen["missed"], len(missed)) :]:
                    # its running period: a stop gives the goal its period again
                    window = max(min(rec["t_s"] - rec["issued_s"], goals.period), WINDOW)
                    recent = self._recent(e, rec["t_s"], window)
                    last = st["stops"]["last_t_s"]  # a stale-camera stop in the goal's period
                    stopped = last is not None and rec["issued_s"] <= last <= rec["t_s"]
                    self._failure(e, "missed_goal", rec["t_s"], recent, stopped)
                count = len(missed) + int(goals.missed_dropped[e])
                for _ in range(count - max(seen["missed"], len(missed))):
                    self._failure(e, "missed_goal", t, self._recent(e, t))
                seen["missed"] = count
            if tracker is not None:
                falls = int(tracker.falls[e])
                for _ in range(falls - seen["falls"]):
                    self._failure(e, "fall", t, self._recent(e, t))
                seen["falls"] = falls

    @staticmethod
    def _fault_event(st: dict, ev: dict) -> None:
        """A fault of the soak's own schedule just judged: ``camera_stop`` names the camera
        fault of a stale-camera stop in its window (armed to judged), whose stop its response
        counts (``latched``, ``resumed``, ``safe_stop``); None without one."""
        start = ev["start_s"] - ARM_LEAD
        end = ev["start_s"] + ev["duration_s"] + FAULT_SETTLE
        hits = [label for t, label in st["recent_stops"] if start <= t <= end]
        stopped = ev["response"] in ("latched", "resumed", "safe_stop")  # not held, not_running
        ev["camera_stop"] = f"camera: {hits[-1]}" if hits and stopped else None

    def _latch(self, e: int, latch: dict, t: float) -> None:
        """A new latch: ``injected`` (stopped safely) when it followed a stale-camera stop that
        followed a camera fault; else a failure, by the camera faults before its stop."""
        last = self.state[e]["last_stop"]
        camera = last.get("camera") if last else None
        if latch.get("cause") == "stale_sensor" and camera not in (None, "none"):
            latch["injected"] = f"camera: {camera}"
            return
        latch["injected"] = None
        if last is None:
            recent = self._recent(e, t)
        elif last.get("before") is not None:
            recent = last["before"]
        else:  # a stale-camera stop with no camera fault before it
            recent = self._recent(e, last["t_s"])
        latch["camera"] = self._failure(e, "latched", float(last["t_s"]) if last else t, recent)

    # ------------------------------------------------------------------ result
    def section(self, e: int, camera: dict) -> dict:
        """Session ``e``'s verdict, for the result's ``camera`` section (``camera``: that
        section's plant counts and drawn faults): ``survived`` (per-frame faults that met the
        camera and stopped nothing, and the session-wide ones), ``stopped_safely`` (fault ->
        stale-camera stops after it), ``frames`` (per-frame fault -> frames hit; ``frozen``
        with its ``spells``), ``stops`` (``count``, ``by_fault``, ``sample``,
        ``sample_limit``), ``latched_after_camera`` (latches with an injected camera cause,
        ``ran_again`` of them), ``failures`` (failure -> label -> count, ``sample``,
        ``not_kept``)."""
        st, s = self.state[e], self.batch.sessions[e]
        stops = st["stops"]
        subs = camera.get("cameras") or {None: camera}  # several cameras: each one's counts
        spells = sum(
            math.ceil(c["frozen"] / max(int(c["faults"]["freeze_frames"]), 1))
            for c in subs.values()
        )
        frames = {
            "frozen": sum(c["frozen"] for c in subs.values()),
            "dropped": sum(c["dropped"] for c in subs.values()),
            "late": sum(c["spiked"] for c in subs.values()),
        }
        after = {  # by the stop's first fault: a frozen spell, else dropped, else late frames
            kind: sum(n for label, n in stops["by_fault"].items() if fault_kind(label) == kind)
            for kind in frames
        }
        session_wide = [
            f"{name}: {w}" if name is not None else w
            for name, c in subs.items()
            for w in throughout(c["faults"], c.get("kind", "depth"))
        ]
        injected = [x for x in s.latches if x.get("injected")]
        own = [ev for ev in s.fault_events if ev.get("camera_stop")]
        return {
            "survived": [
                *(k for k, n in frames.items() if n and not after[k]),
                *session_wide,
            ],
            "stopped_safely": {k: n for k, n in after.items() if n},
            "frames": {**frames, "frozen_spells": spells},
            "stops": {
                "count": stops["count"],
                "by_fault": dict(stops["by_fault"]),
                "sample": stops["sample"],
                "sample_limit": STOP_SAMPLE,
            },
            "latched_after_camera": {
                "count": len(injected),
                "ran_again": sum(1 for x in injected if x.get("running_again_s") is not None),
                "operator_reset_s": s.config.operator_reset,
            },
            # the soak's own faults whose response was a camera's stop in their window
            "own_faults_judged_with_a_camera_stop": len(own),
            "failures": {
                "counts": st["failures"]["counts"],
                "sample": st["failures"]["sample"],
                "not_kept": st["failures"]["dropped"],
                "window_s": WINDOW,
            },
        }

    # ------------------------------------------------------------------ state
    def state_dict(self, env: int | None = None) -> dict:
        """``verdict``: JSON text, a list over the envs (of env ``env`` alone when given) of
        each session's counts, samples and what it has seen."""
        return records_json({"verdict": self.state}, env_list(len(self.state), env))

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`.

        Raises:
            StateDictError: the field missing, not JSON or not a list of the envs."""
        envs = env_list(len(self.state), env)
        for e, value in zip(
            envs, read_records(state, ["verdict"], len(envs))["verdict"], strict=True
        ):
            self.state[e] = value
