"""Soak film strip, after the session: each session's clips replayed exactly from the checkpoints
kept during it (:mod:`sim2real.eval.film.strip`) and rendered.

After the campaign, :func:`film_campaign` renders every session in its own process (``python -m
sim2real.eval.film.render``, several at once; ``MUJOCO_GL=egl`` where nothing is chosen and there is no
display): for each moment (:func:`sim2real.eval.film.strip.select_moments`, grouped into clips by
:func:`sim2real.eval.film.strip.plan_clips`) it resumes the session from the nearest kept checkpoint before
the clip (or from its start), runs it through the same harness tick by tick with the same seed and
fault schedule, and draws env 0 with :class:`sim2real.deploy.observe.video.VideoRecorder` (the session's
randomized model; goal sphere, end-effector trail, links tinted where the guard acts). At the
moment's tick the replayed true joint positions are compared with the recorded ones, bit for bit
(``replay_exact``). A policy with state no checkpoint holds (the adversarial policy draws its
actions inside ONNX Runtime) replays exactly only from the session's start: a clip whose replay
differed is rendered again from there when it begins within ``RETRY_S``, and reported as
differing otherwise.

Output, per session: ``OUT/film/<id>/NN-<kind>.mp4`` (H.264, ``FPS`` frames per s of simulated
time, ``SIZE`` pixels), ``NN-<kind>.png`` (the frame at the moment) and ``film.json``; after a
session's film is rendered its kept checkpoints are deleted. An 8-hour session's film is at
most ``MAX_CLIPS`` clips of ``MAX_CLIP_S`` s, whatever the session's length.
:mod:`sim2real.eval.report.build` embeds the clips in report.html and names the stills in junit.xml.

Without an OpenGL context (or without imageio-ffmpeg) the film is left out with a one-line
note naming ``MUJOCO_GL``; the soak's results and exit code do not depend on it.
"""

from __future__ import annotations

import math
import os
import pickle
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from sim2real.deploy.core.registry import Faces
from sim2real.deploy.kinds import robot_kind
from sim2real.eval.film.strip import (
    FILM,
    FINAL,
    KINDS,
    MAX_CLIPS,
    STATE,
    FilmError,
    film_dir,
    kept_checkpoints,
    plan_clips,
    read_json,
    recorder_state,
    retain_dir,
    select_moments,
    write_json,
)

#: The film of each robot kind, by its name (:class:`sim2real.deploy.core.registry.Faces`):
#: ``(session result) -> None`` (filmed) or the one-line reason it is not: a walking session
#: (:class:`sim2real.deploy.observe.video.VideoRecorder` draws the joints over a fixed base).
FILM_OF_KIND: Faces = Faces("film")


def _filmed(result: dict) -> None:
    """An arm's session: filmed."""
    return None


def _walking_not_filmed(result: dict) -> str | None:
    """A legged robot's session: filmed unless it walked (its report has ``locomotion``)."""
    if result.get("locomotion") is None:
        return None
    return "a legged robot's session: the film draws fixed-base arms only"


FILM_OF_KIND.register("arm", _filmed)
FILM_OF_KIND.register("legged", _walking_not_filmed)

#: Frames per simulated second, pixels (width, height), x264 rate factor of the clips.
FPS = 20.0
SIZE = (480, 360)
CRF = 28
#: s: a clip whose replay from a checkpoint differed is replayed from the session's start if
#: it begins within this time (a policy with state outside the checkpoint; our choice).
RETRY_S = 900.0
#: Exit code of ``python -m sim2real.eval.film.render`` when no film can be made here (no GL, no
#: ffmpeg).
EXIT_NO_FILM = 3


# ====================================================================== replay and render
class _Replay:
    """A one-session batch positioned anywhere in the session: resumed from the nearest kept
    checkpoint at or before the wanted tick (or started afresh), then stepped by the harness's
    own per-tick hook."""

    def __init__(self, config, out: Path, work: Path):
        self.config, self.out, self.work = config, out, work
        self.kept = kept_checkpoints(out, config.seed)
        self.batch = None
        self.loaded_from = 0
        self.simulated_ticks = 0

    def _load(self, tick: int, from_start: bool) -> None:
        from sim2real.eval.soak.batch import SessionBatch
        from sim2real.eval.soak.session import session_dir

        best = 0 if from_start else max((t for t in self.kept if t <= tick), default=0)
        if self.batch is not None and best <= self.batch.rt.ticks <= tick:
            if not from_start or self.loaded_from == 0:
                return  # stepping on is no longer than resuming
        self.batch = None
        shutil.rmtree(self.work, ignore_errors=True)
        if best > 0:
            d = session_dir(self.work, self.config.seed)
            d.mkdir(parents=True)
            for f in self.kept[best].iterdir():
                if f.is_file() and f.name != STATE:
                    shutil.copy2(f, d / f.name)
        self.batch = SessionBatch([self.config], self.work, resume=best > 0, progress=False)
        self.loaded_from = best
        if self.batch.rt.ticks != best:
            raise FilmError(
                f"{self.kept[best]}: resumed at tick {self.batch.rt.ticks}, expected {best}"
            )

    def advance_to(self, tick: int, from_start: bool = False) -> None:
        """Position the replay at ``tick`` (from the nearest kept checkpoint, or with
        ``from_start`` from the session's start)."""
        self._load(tick, from_start)
        n = tick - self.batch.rt.ticks
        if n > 0:
            self.batch.rt.run(n, on_tick=self.batch.on_tick)
            self.simulated_ticks += n


def _save_png(path: Path, frame: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(np.ascontiguousarray(frame)).save(path, optimize=True)


def _render_clip(
    replay: _Replay, c: dict, dest: Path, name: str, dt: float, from_start: bool, look: dict
):
    """Replay clip ``c`` (``start_s``..``end_s``) and render it to ``dest/name.mp4`` and the
    still at its first moment to ``dest/name.png`` (``look``: ``fps``, ``size``, ``crf``); the
    clip's entry of ``film.json``."""
    from sim2real.deploy.observe.video import VideoRecorder

    first = c["moments"][0]
    t0 = int(math.floor(c["start_s"] / dt + 1e-9))
    t1 = int(math.ceil(c["end_s"] / dt - 1e-9))
    replay.advance_to(t0, from_start=from_start)
    from_tick = replay.loaded_from
    b = replay.batch
    rt = b.rt
    try:
        video = VideoRecorder(
            b.robot,
            dest / f"{name}.mp4",
            look["fps"],
            tuple(look["size"]),
            None,
            b.backend.true_position,
            model=b.backend.models[0],
            start=rt.time,
            crf=look["crf"],
            verbose=False,
        )
    except (RuntimeError, ImportError) as exc:
        raise FilmError(str(exc)) from None
    checks = {m["tick"]: m for m in c["moments"] if m.get("q") is not None}
    exact: dict[int, bool] = {}
    still = {"frame": None}

    def on_tick(r) -> bool:
        b.on_tick(r)
        frames = video.frames
        video(r)
        m = checks.get(r.ticks)
        if m is not None:
            q = b.backend.true_position()[0]
            exact[r.ticks] = bool(np.array_equal(q, np.asarray(m["q"])))
        if still["frame"] is None and r.ticks >= first["tick"] and video.frames > frames:
            still["frame"] = video.last_frame.copy()
        return False

    n = max(t1 - t0, 1)
    rt.run(n, on_tick=on_tick)
    replay.simulated_ticks += n
    path = video.close()
    frame = still["frame"] if still["frame"] is not None else video.last_frame
    _save_png(dest / f"{name}.png", frame)
    return {
        "kind": first["kind"],
        "label": "; ".join(m["label"] for m in c["moments"]),
        "kinds": sorted({m["kind"] for m in c["moments"]}),
        "moments": [{k: m[k] for k in ("kind", "label", "t_s", "tick")} for m in c["moments"]],
        "t_s": first["t_s"],
        "start_s": t0 * dt,
        "end_s": (t0 + n) * dt,
        "frames": video.frames,
        "bytes": path.stat().st_size,
        "replay_exact": (all(exact.values()) if exact else None),
        "checked": len(exact),
        "from_tick": from_tick,
        "render_s": video.render_s,
    }


def render_session(
    config,
    out: str | os.PathLike,
    stream=None,
    fps: float = FPS,
    size: tuple[int, int] = SIZE,
    max_clips: int = MAX_CLIPS,
    crf: int = CRF,
) -> dict:
    """Render session ``config.seed``'s film from its kept checkpoints and recorder state into
    ``OUT/film/<id>/`` (clips, stills, ``film.json``) and return ``film.json``'s document.

    Args:
        config: The session's :class:`sim2real.eval.soak.session.SessionConfig`.
        out: The campaign folder.
        stream: Where to print one summary line (None: nowhere).
        fps, size, max_clips, crf: Frames per simulated second, (width, height) pixels, clips
            at most, x264 rate factor (defaults ``FPS``, ``SIZE``, ``MAX_CLIPS``, ``CRF``).

    Raises:
        FilmError: the session has no result, or no film can be made (no OpenGL context: the
            message names ``MUJOCO_GL``; imageio-ffmpeg missing).
    """
    from sim2real.eval.soak.result import read_result
    from sim2real.robots import load_robot

    out = Path(out)
    result = read_result(out, config.seed)
    if result is None:
        raise FilmError(f"session {config.id}: no result.json in {out}; nothing to film")
    state = recorder_state(out, config.seed)
    wall = time.perf_counter()
    replay = _Replay(config, out, out / FILM / f".replay-{config.id}")
    dest = film_dir(out, config.id)
    shutil.rmtree(dest, ignore_errors=True)
    dest.mkdir(parents=True)
    dt = load_robot(config.robot).control_period
    clips_out, render_s = [], 0.0
    try:
        moments = select_moments(state, result, dt)
        clips, dropped = plan_clips(moments, max_clips)
        look = {"fps": fps, "size": size, "crf": crf}
        for index, c in enumerate(clips, start=1):
            name = f"{index:02d}-{c['moments'][0]['kind']}"
            clip = _film_clip(replay, c, out, dest, name, dt, look)
            render_s += clip.pop("render_s")
            clips_out.append(clip)
    finally:
        replay.batch = None
        shutil.rmtree(replay.work, ignore_errors=True)
    doc = {
        "session": config.id,
        "seed": config.seed,
        "policy_sha256": result.get("policy_sha256"),
        "simulated_s": result["simulated_s"],
        "options": result.get("options"),
        "clips": clips_out,
        "moments": _moments_found(moments, state),
        "not_filmed": dropped
        + int((state or {}).get("hard_more", 0))
        + int((state or {}).get("latched_more", 0)),
        "unknown_before_s": (state or {}).get("unknown_before_s"),
        "recorded": state is not None,
        "fps": fps,
        "max_clips": max_clips,
        "size": list(size),
        "replayed_s": replay.simulated_ticks * dt,
        "render_s": render_s,
        "wall_s": time.perf_counter() - wall,
        "frames_per_s": (sum(c["frames"] for c in clips_out) / render_s if render_s else None),
    }
    write_json(dest / "film.json", doc)
    if stream is not None:
        exact = [c["replay_exact"] for c in clips_out if c["replay_exact"] is not None]
        print(
            f"film: {config.id}: {len(clips_out)} clips ({sum(c['bytes'] for c in clips_out)} "
            f"bytes), replay exact {sum(exact)}/{len(exact)}, {doc['wall_s']:.1f} s",
            file=stream,
        )
    return doc


def _film_clip(replay, c: dict, out: Path, dest: Path, name: str, dt: float, look: dict) -> dict:
    """Clip ``c`` rendered to ``dest/<name>.mp4`` and its still (their paths in the campaign
    folder); replayed from the session's own start where the checkpoint's replay was not exact
    (a policy keeping state a checkpoint cannot hold, e.g. a random stream inside the graph)."""
    clip = _render_clip(replay, c, dest, name, dt, False, look)
    if clip["replay_exact"] is False and clip["from_tick"] > 0 and c["start_s"] <= RETRY_S:
        clip = _render_clip(replay, c, dest, name, dt, True, look)
    clip["video"] = (dest / f"{name}.mp4").relative_to(out).as_posix()
    clip["still"] = (dest / f"{name}.png").relative_to(out).as_posix()
    return clip


def _moments_found(moments: list[dict], state: dict | None) -> dict[str, int]:
    """Moments of each kind found, those the recorder counted past its list included."""
    found = {k: 0 for k in KINDS}
    for m in moments:
        found[m["kind"]] += 1
    if state:
        found["hard_violation"] += int(state.get("hard_more", 0))
        found["latched_fault"] += int(state.get("latched_more", 0))
    return found


# ====================================================================== the campaign's film
def _summary(doc: dict) -> dict:
    """What report.json keeps of a session's film.json."""
    keys = ("clips", "moments", "not_filmed", "max_clips", "unknown_before_s", "fps", "size")
    keys += ("frames_per_s",)
    return {k: doc.get(k) for k in keys} | {"error": None}


def _finished(out: Path, result: dict) -> dict | None:
    """The film already rendered for this very session result, or None."""
    if (retain_dir(out, result["seed"]) / FINAL).exists():
        return None  # recorded anew since: render anew
    doc = read_json(film_dir(out, result["id"]) / "film.json")
    if not doc or doc.get("seed") != result["seed"]:
        return None
    if doc.get("policy_sha256") != result.get("policy_sha256"):
        return None
    if doc.get("simulated_s") != result.get("simulated_s"):
        return None
    if doc.get("options") != result.get("options"):
        return None
    if not all((out / c["video"]).is_file() for c in doc["clips"]):
        return None
    return doc


def film_campaign(
    template,
    results: list[dict],
    out: str | os.PathLike,
    workers: int | None = None,
    **look,
) -> list[dict]:
    """Render the film of every session of a campaign (one process per session, ``workers`` at
    once, default one per core) and return the results with ``film`` added: the clips
    (``kind``, ``label``, ``t_s``, ``start_s``, ``end_s``, ``video`` and ``still`` paths relative
    to ``out``, ``replay_exact``), ``moments`` found per kind, ``not_filmed``, and ``error`` (a
    one-line reason when no film could be made, else None). A session whose film was already
    rendered (a resumed campaign) is not rendered again; a session whose robot kind's film face
    (:data:`FILM_OF_KIND`: a walking session's) gives a reason gets none (its ``error`` says
    so). Prints
    one line per session.

    Args:
        template: The campaign's :class:`sim2real.eval.soak.session.SessionConfig` (sessions differ by seed).
        results: Session results (:func:`sim2real.eval.soak.campaign.run_campaign`).
        out: The campaign folder.
        workers: Processes rendering at once.
        **look: ``fps``, ``size``, ``max_clips``, ``crf`` of :func:`render_session`.
    """
    from dataclasses import replace

    from sim2real.deploy.observe.video import headless_gl_default
    from sim2real.eval.soak.executors import default_workers

    out = Path(out)
    env = dict(os.environ)
    headless_gl_default(env)
    env.setdefault("ORT_DISABLE_TELEMETRY", "1")
    docs: dict[int, dict] = {}
    todo = []
    for r in results:
        doc = _finished(out, r)
        if doc is not None:
            docs[r["seed"]] = _summary(doc)
        else:
            todo.append(r)

    from sim2real.robots import load_robot

    no_film = FILM_OF_KIND.get(robot_kind(load_robot(template.robot)))

    def render(r: dict) -> tuple[int, dict]:
        reason = no_film(r)  # the robot's kind's film face: why not, or None
        if reason is not None:
            shutil.rmtree(retain_dir(out, r["seed"]), ignore_errors=True)
            print(f"film: {r['id']}: no film: {reason}", file=sys.stderr)
            return r["seed"], {"clips": [], "error": reason}
        config = replace(template, seed=r["seed"])
        done = subprocess.run(
            [sys.executable, "-m", "sim2real.eval.film.render"],
            input=pickle.dumps((config, str(out), look)),
            capture_output=True,
            env=env,
        )
        if done.returncode == 0:
            doc = read_json(film_dir(out, r["id"]) / "film.json")
            if doc is not None:
                shutil.rmtree(retain_dir(out, r["seed"]), ignore_errors=True)
                print(done.stdout.decode(errors="replace").strip())
                return r["seed"], _summary(doc)
        lines = done.stderr.decode(errors="replace").strip().splitlines() or ["no output"]
        reason = lines[-1]
        print(f"film: {r['id']}: no film: {reason}", file=sys.stderr)
        return r["seed"], {"clips": [], "error": reason}

    if todo:
        n = max(1, min(workers or default_workers(), len(todo)))
        with ThreadPoolExecutor(max_workers=n) as pool:
            for seed, doc in pool.map(render, todo):
                docs[seed] = doc
    return [{**r, "film": docs[r["seed"]]} for r in results]


def _main() -> int:
    """``python -m sim2real.eval.film.render`` with a pickled ``(SessionConfig, out)`` on standard input
    (from :func:`film_campaign`, the same program's parent: trusted)."""
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    config, out, look = pickle.loads(sys.stdin.buffer.read())
    try:
        render_session(config, out, sys.stdout, **look)
    except FilmError as exc:
        print(f"film: {exc}", file=sys.stderr)
        return EXIT_NO_FILM
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
