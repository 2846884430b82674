"""Soak film strip, during the session: the kept checkpoints, the moments worth filming and the
clips planned around them.

A soak session is a function of its seed and options, and resumes from any of its checkpoints
to the same result bit for bit (:mod:`sim2real.eval.soak`). The film strip uses that: while a session
runs, :class:`FilmRecorder` (a recorder of :class:`sim2real.eval.soak.batch.SessionBatch`) keeps
a copy of every checkpoint (``OUT/sessions/<id>/film/<tick>/``: the checkpoint's files, hard links
where the file system allows, and the recorder's own state) and notes, at the harness's
supervision steps (every ``sim2real.eval.soak.batch.SUPERVISE_PERIOD`` s), when a hard-limit violation of the
true state or a hard-limit safe stop of the runtime begins, when a fault latches and when the
hottest winding temperature so far occurs, each with the tick and the true joint positions then
(the replay's fingerprint). After the campaign, :mod:`sim2real.eval.film.render` replays each session
from these checkpoints and renders the clips that :func:`select_moments` and :func:`plan_clips`
choose here.

The moments (``KINDS``): every hard violation (a run of supervision steps in which the true-state
``hard_limit`` counter or the runtime's hard-limit safe stops rose), every latched fault, the
hottest minute (the minute holding the highest winding temperature of any joint, clip around its
instant) and the longest run of missed goals (consecutive goals replaced unreached, from the
session's ``goals.missed``; the clip shows up to ``MAX_CLIP_S`` s from its first goal's issue). A
clip runs ``BEFORE_S`` s before to ``AFTER_S`` s after its moment; moments whose clips overlap
share one (up to ``MAX_CLIP_S`` s). At most ``MAX_CLIPS`` clips per session, in this order: the
first hard violation, the first latched fault, the hottest minute, the longest run of missed goals,
then the other hard violations and latched faults by time; the rest are counted (``not_filmed``).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from sim2real.robots.errors import Sim2RealError
from sim2real.robots.files import atomic_write

#: Folder of the rendered film under the campaign folder, and of the kept checkpoints under a
#: session's folder.
FILM = "film"
#: The recorder's state in a kept checkpoint's folder, and at a session's end.
STATE = "recorder.json"
FINAL = "final.json"
KINDS = ("hard_violation", "latched_fault", "hottest_minute", "missed_goals")
#: A hard violation's two sources: the true state (simulation) and the runtime's safe stop.
HARD_WHAT = {
    "true": "hard-limit violation (true state)",
    "stop": "hard-limit safe stop (estimate beyond a hard limit)",
}
#: Clips per session (our choice: an 8-hour report stays about 1 MB per session).
MAX_CLIPS = 8
#: s of simulated time shown before and after a moment, and the longest clip.
BEFORE_S = 3.0
AFTER_S = 3.0
MAX_CLIP_S = 10.0
#: Moments of one kind the recorder keeps per session (later ones are only counted).
MAX_RECORDED = 200


class FilmError(Sim2RealError, RuntimeError):
    """No film can be made (no OpenGL context, no writer, no kept state); one line."""


def retain_dir(out: str | os.PathLike, seed: int) -> Path:
    """``OUT/sessions/<id>/film``: the checkpoints kept for session ``seed``'s film."""
    from sim2real.eval.soak.session import session_dir

    return session_dir(out, seed) / FILM


def film_dir(out: str | os.PathLike, session_id: str) -> Path:
    """``OUT/film/<id>``: a session's rendered clips, stills and ``film.json``."""
    return Path(out) / FILM / session_id


def read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def write_json(path: Path, doc) -> None:
    atomic_write(path, json.dumps(doc))


# ====================================================================== during the session
class FilmRecorder:
    """The soak's film hook: keeps every checkpoint and notes the moments worth filming.

    :class:`sim2real.eval.soak.batch.SessionBatch` (``recorders=(FilmRecorder,)``) calls :meth:`supervise`
    at each supervision step, :meth:`checkpointed` after writing its checkpoints and
    :meth:`finish` at the end. It only reads the batch: the session's results are the same with
    or without it.

    A moment is ``{"t_s": s, "tick": control tick, "q": true joint positions then, rad}`` plus
    ``count`` (hard violations: the ``hard_limit`` tick counter), ``cause`` (latched faults) or
    ``c`` and ``joint`` (the hottest winding, degC).
    """

    def __init__(self, batch):
        self.batch = batch
        rt = batch.rt
        self.states = []
        for s in batch.sessions:
            state = None
            if rt.ticks > 0:  # resumed: the recorder's state kept with that checkpoint
                kept = retain_dir(batch.out, s.config.seed)
                state = read_json(kept / f"{rt.ticks:012d}" / STATE)
            if state is None:
                state = {
                    "hard": [],
                    "hard_more": 0,
                    "hard_last": int(batch.violations.counts["hard_limit"][s.e]),
                    "stop_last": int(rt.counters.faults["hard_limit"][s.e]),
                    "hard_active": False,
                    "latched": [],
                    "latched_more": 0,
                    "latch_seen": len(s.latches),
                    "peak": None,
                    # resumed without a kept state (film was off): moments before are unknown
                    "unknown_before_s": float(rt.time) if rt.ticks > 0 else None,
                }
            self.states.append(state)

    def _moment(self, e: int, **extra) -> dict:
        rt = self.batch.rt
        q = self.batch.backend.true_position()[e]
        return {"t_s": float(rt.time), "tick": int(rt.ticks), "q": [float(x) for x in q], **extra}

    def supervise(self, rt) -> None:
        """Note this supervision step's moments (cheap: a few comparisons per session)."""
        b = self.batch
        hard = b.violations.counts["hard_limit"]
        stops = rt.counters.faults["hard_limit"]
        temp = b.backend.thermal.winding_temperature
        names = b.robot.joint_names
        for s, st in zip(b.sessions, self.states, strict=True):
            e = s.e
            count, stop = int(hard[e]), int(stops[e])
            rose = [
                w
                for w, up in (
                    ("true", count > st["hard_last"]),
                    ("stop", stop > st.get("stop_last", 0)),
                )
                if up
            ]
            if rose:
                if not st["hard_active"]:
                    if len(st["hard"]) < MAX_RECORDED:
                        st["hard"].append(self._moment(e, count=count, what=rose))
                    else:
                        st["hard_more"] += 1
                st["hard_active"] = True
            else:
                st["hard_active"] = False
            st["hard_last"], st["stop_last"] = count, stop
            if len(s.latches) > st["latch_seen"]:
                for latch in s.latches[st["latch_seen"] :]:
                    if len(st["latched"]) < MAX_RECORDED:
                        st["latched"].append(self._moment(e, cause=latch.get("cause")))
                    else:
                        st["latched_more"] += 1
                st["latch_seen"] = len(s.latches)
            j = int(np.argmax(temp[e]))
            hottest = float(temp[e, j])
            if st["peak"] is None or hottest > st["peak"]["c"]:
                st["peak"] = self._moment(e, c=hottest, joint=names[j])

    def checkpointed(self) -> None:
        """Keep a copy of each session's checkpoint just written, with the recorder's state."""
        from sim2real.eval.soak.session import session_dir

        b = self.batch
        tick = int(b.rt.ticks)
        for s, st in zip(b.sessions, self.states, strict=True):
            src = session_dir(b.out, s.config.seed)
            dst = retain_dir(b.out, s.config.seed) / f"{tick:012d}"
            tmp = dst.with_name(dst.name + ".part")
            shutil.rmtree(tmp, ignore_errors=True)
            tmp.mkdir(parents=True)
            for f in src.iterdir():
                if not f.is_file() or f.name in ("progress.json", "result.json"):
                    continue
                if f.name.endswith(".part"):
                    continue
                try:
                    os.link(f, tmp / f.name)  # the checkpoint writer replaces, never rewrites
                except OSError:
                    shutil.copy2(f, tmp / f.name)
            write_json(tmp / STATE, {**st, "tick": tick})
            shutil.rmtree(dst, ignore_errors=True)
            os.replace(tmp, dst)

    def finish(self) -> None:
        """Write each session's final recorder state (``film/final.json``)."""
        b = self.batch
        for s, st in zip(b.sessions, self.states, strict=True):
            d = retain_dir(b.out, s.config.seed)
            d.mkdir(parents=True, exist_ok=True)
            write_json(d / FINAL, {**st, "tick": int(b.rt.ticks)})


def kept_checkpoints(out: str | os.PathLike, seed: int) -> dict[int, Path]:
    """Tick -> folder of the checkpoints kept for session ``seed``'s film."""
    d = retain_dir(out, seed)
    if not d.is_dir():
        return {}
    return {int(p.name): p for p in d.iterdir() if p.is_dir() and p.name.isdigit()}


def recorder_state(out: str | os.PathLike, seed: int) -> dict | None:
    """The recorder's state at the session's end (or at its last kept checkpoint)."""
    final = read_json(retain_dir(out, seed) / FINAL)
    if final is not None:
        return final
    kept = kept_checkpoints(out, seed)
    return read_json(kept[max(kept)] / STATE) if kept else None


# ====================================================================== what to film
def longest_missed_run(missed: list[dict]) -> list[dict]:
    """The longest run of consecutive missed goals (each issued when the previous one was
    replaced unreached: ``issued_s`` equal to the previous ``t_s``); the first if tied."""
    best: list[dict] = []
    run: list[dict] = []
    for m in missed:
        if run and m["issued_s"] == run[-1]["t_s"]:
            run.append(m)
        else:
            run = [m]
        if len(run) > len(best):
            best = list(run)
    return best


def select_moments(state: dict | None, result: dict, dt: float) -> list[dict]:
    """Every moment worth filming, in priority order (module docstring), each with ``kind``,
    ``label``, ``t_s``, ``tick``, ``q`` (the fingerprint, or None), and the clip's wanted
    ``start_s`` and ``end_s``."""
    end = float(result["simulated_s"])

    def clip(m: dict, kind: str, label: str, start=None, stop=None) -> dict:
        t = float(m["t_s"])
        start = max(0.0, t - BEFORE_S) if start is None else start
        stop = min(end, t + AFTER_S) if stop is None else stop
        return {
            "kind": kind,
            "label": label,
            "t_s": t,
            "tick": int(m.get("tick", round(t / dt))),
            "q": m.get("q"),
            "start_s": start,
            "end_s": max(stop, start),
        }

    state = state or {}
    hard = [
        clip(
            m,
            "hard_violation",
            " and ".join(HARD_WHAT[w] for w in m.get("what", ["true"])) + f" at {m['t_s']:.1f} s",
        )
        for m in state.get("hard", [])
    ]
    latches = state.get("latched")
    if latches is None:  # no recorder state: the result's latches, without a fingerprint
        latches = [{"t_s": x["t_s"], "cause": x.get("cause")} for x in result["runtime"]["latches"]]
    latched = [
        clip(
            m, "latched_fault", f"latched fault ({m.get('cause') or 'unknown'}) at {m['t_s']:.1f} s"
        )
        for m in latches
    ]
    first: list[dict] = []
    if hard:
        first.append(hard.pop(0))
    if latched:
        first.append(latched.pop(0))
    peak = state.get("peak")
    if peak is not None:
        minute = int(peak["t_s"] // 60)
        first.append(
            clip(
                peak,
                "hottest_minute",
                f"hottest minute (minute {minute}): {peak['joint']} winding {peak['c']:.1f} degC "
                f"at {peak['t_s']:.1f} s",
            )
        )
    run = longest_missed_run((result.get("goals") or {}).get("missed", []))
    if run:
        start = max(0.0, run[0]["issued_s"] - 1.0)
        stop = min(end, run[-1]["t_s"] + AFTER_S, start + MAX_CLIP_S)
        first.append(
            clip(
                run[0],
                "missed_goals",
                f"longest run of missed goals: {len(run)} in a row, {run[0]['issued_s']:.1f} s "
                f"to {run[-1]['t_s']:.1f} s",
                start,
                stop,
            )
        )
    rest = sorted(hard + latched, key=lambda m: m["t_s"])
    return first + rest


def plan_clips(moments: list[dict], max_clips: int = MAX_CLIPS) -> tuple[list[dict], int]:
    """Group moments into clips: a moment joins a clip it overlaps if the union stays within
    ``MAX_CLIP_S``, else opens a new one while fewer than ``max_clips`` exist.

    Returns:
        (clips sorted by start, each ``{start_s, end_s, moments}``; moments not filmed).
    """
    clips: list[dict] = []
    dropped = 0
    for m in moments:
        for c in clips:
            lo, hi = min(c["start_s"], m["start_s"]), max(c["end_s"], m["end_s"])
            if m["start_s"] <= c["end_s"] and c["start_s"] <= m["end_s"] and hi - lo <= MAX_CLIP_S:
                c["start_s"], c["end_s"] = lo, hi
                c["moments"].append(m)
                break
        else:
            if len(clips) < max_clips:
                clips.append({"start_s": m["start_s"], "end_s": m["end_s"], "moments": [m]})
            else:
                dropped += 1
    clips.sort(key=lambda c: c["start_s"])
    return clips, dropped
