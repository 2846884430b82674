"""The soak's film strip (sim2real.eval.film.strip, sim2real.eval.film.render): moments, replay from checkpoints, clips in
report.html, and the clip playing in a real headless browser (Chromium through Selenium)."""

import json
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from sim2real.eval.film.strip import (
    FilmRecorder,
    longest_missed_run,
    plan_clips,
    retain_dir,
    select_moments,
)
from sim2real.eval.report.build import build_report, write_reports
from sim2real.eval.report.schema import Thresholds
from sim2real.eval.soak.campaign import run_campaign
from sim2real.eval.soak.session import SessionConfig
from sim2real.eval.world.fault_schedule import FaultRanges
from sim2real.eval.world.session_ranges import SessionRanges
from tests.runtime_fixtures import adversarial_onnx

#: Pushes far beyond what the drives hold: the adversarial policy's arm is thrown past a hard
#: limit (true state) and the guard's hard-limit safe stop latches.
HARD_PUSHES = FaultRanges(
    mean_interval=15.0,
    warmup=5.0,
    kinds=("push",),
    push_force=(1500.0, 3000.0),
    push_duration=(0.3, 0.6),
)
LOOK = {"fps": 10.0, "size": (240, 180), "max_clips": 2}
#: The tests of the filmed session, on one pytest-xdist worker (make test's --dist loadgroup):
#: the module fixture films it once per worker.
ON_ONE_WORKER = pytest.mark.xdist_group("film")


def egl_works() -> bool:
    probe = (
        "import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco/>'); "
        "mujoco.Renderer(m, 32, 32).render()"
    )
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    done = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True)
    return done.returncode == 0


# ---------------------------------------------------------------------- what to film
def missed(issued, t):
    return {"issued_s": issued, "t_s": t, "q": [0.0, 0.0, 0.0]}


def test_the_longest_run_of_missed_goals_is_consecutive_goals():
    runs = [missed(0.0, 4.0), missed(8.0, 12.0), missed(12.0, 16.0), missed(16.0, 20.0)]
    runs += [missed(30.0, 34.0), missed(34.0, 38.0)]
    assert [m["t_s"] for m in longest_missed_run(runs)] == [12.0, 16.0, 20.0]
    assert longest_missed_run([]) == []


def test_moments_in_priority_order_and_clips_capped_and_merged():
    state = {
        "hard": [{"t_s": 50.0, "tick": 10000, "q": [0.0] * 3, "what": ["true", "stop"]}]
        + [{"t_s": 100.0 + 20 * k, "tick": 0, "q": None} for k in range(12)],
        "latched": [{"t_s": 51.0, "tick": 10200, "q": [0.0] * 3, "cause": "hard_limit"}],
        "peak": {"t_s": 400.0, "tick": 80000, "q": [0.0] * 3, "c": 90.5, "joint": "elbow"},
    }
    result = {
        "simulated_s": 600.0,
        "runtime": {"latches": []},
        "goals": {"missed": [missed(300.0, 304.0), missed(304.0, 308.0)]},
    }
    moments = select_moments(state, result, 0.005)
    kinds = [m["kind"] for m in moments[:4]]
    assert kinds == ["hard_violation", "latched_fault", "hottest_minute", "missed_goals"]
    assert "safe stop" in moments[0]["label"] and "true state" in moments[0]["label"]
    assert "elbow winding 90.5 degC" in moments[2]["label"]
    assert moments[3]["start_s"] == 299.0 and moments[3]["end_s"] == 309.0
    clips, dropped = plan_clips(moments, 8)
    assert len(clips) == 8 and dropped == len(moments) - 8 - 1  # the latch joined the first
    first = clips[0]
    assert [m["kind"] for m in first["moments"]] == ["hard_violation", "latched_fault"]
    assert first["start_s"] == 47.0 and first["end_s"] == 54.0
    assert all(c["end_s"] - c["start_s"] <= 10.0 for c in clips)
    assert [c["start_s"] for c in clips] == sorted(c["start_s"] for c in clips)


# ---------------------------------------------------------------------- a soak on film
@pytest.fixture(scope="module")
def filmed(tmp_path_factory, arm3):
    """A 32-s session of the adversarial policy, thrown past a hard limit by a push at 25.3 s,
    checkpointed every 15 s; its film rendered small (240x180, 10 fps, 2 clips)."""
    if not egl_works():
        pytest.skip("no EGL OpenGL context here (MUJOCO_GL=egl): the film cannot be rendered")
    from sim2real.eval.film.render import film_campaign

    tmp = tmp_path_factory.mktemp("film")
    policy = adversarial_onnx(tmp, arm3, "velocity")
    config = SessionConfig(
        robot="arm3",
        policy=str(policy),
        hours=32.0 / 3600.0,
        checkpoint_minutes=0.25,
        curve_seconds=10.0,
        ranges=SessionRanges(faults=HARD_PUSHES),
    )
    out = tmp / "soak"
    results = run_campaign(config, 1, out, progress=False, recorders=(FilmRecorder,))
    kept = sorted(p.name for p in retain_dir(out, 0).iterdir())
    results = film_campaign(config, results, out, **LOOK)
    report = build_report({"robot": "arm3"}, results, Thresholds(min_success_rate=0.0))
    paths = write_reports(out, report)
    return out, report, paths, kept


@ON_ONE_WORKER
def test_a_hard_violation_is_filmed_from_an_exact_replay(filmed):
    out, report, _, kept = filmed
    (s,) = report["sessions"]
    assert s["violations"]["total"]["hard_limit"] > 0  # the push threw the arm past a limit
    assert kept == ["000000003000", "000000006000", "final.json"]  # every checkpoint was kept
    assert not retain_dir(out, 0).exists()  # and removed once the film was rendered
    film = s["film"]
    assert film["error"] is None and len(film["clips"]) == 2
    (clip,) = [c for c in film["clips"] if "hard_violation" in c["kinds"]]
    assert "latched_fault" in clip["kinds"]  # the guard's safe stop latched: the same clip
    moment = next(m for m in clip["moments"] if m["kind"] == "hard_violation")
    assert clip["start_s"] + 2.9 <= moment["t_s"] <= clip["end_s"] - 2.9  # 3 s either side
    # the adversarial policy draws inside ONNX Runtime, which no checkpoint holds: its replay
    # from the 15-s checkpoint differed, and the one from the session's start is exact
    assert clip["replay_exact"] is True and clip["checked"] >= 1 and clip["from_tick"] == 0
    assert film["moments"]["hard_violation"] >= 1 and film["moments"]["hottest_minute"] == 1
    filmed_moments = sum(len(c["moments"]) for c in film["clips"])
    assert filmed_moments + film["not_filmed"] == sum(film["moments"].values())

    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(out / clip["video"]))
    meta = next(reader)
    assert meta["codec"].startswith("h264") and meta["size"] == (240, 180)
    frames = [np.frombuffer(f, np.uint8).reshape(180, 240, 3) for f in reader]
    duration = clip["end_s"] - clip["start_s"]
    assert abs(len(frames) - duration * LOOK["fps"]) <= 2
    from PIL import Image

    still = np.asarray(Image.open(out / clip["still"]))
    assert still.shape == (180, 240, 3) and still.std() > 5.0  # the robot, not a blank frame
    # the still is the clip's frame at the moment (H.264 is lossy: close, not equal)
    k = int(round((moment["t_s"] - clip["start_s"]) * LOOK["fps"]))
    errors = [np.abs(frames[i].astype(int) - still).mean() for i in range(len(frames))]
    assert abs(int(np.argmin(errors)) - k) <= 1 and min(errors) < 3.0


@ON_ONE_WORKER
def test_report_embeds_the_clips_and_junit_names_the_still(filmed):
    out, report, paths, _ = filmed
    text = paths["html"].read_text()
    assert text.count("<video") == 2 and "data:video/mp4;base64," in text
    assert "Film: the worst moments" in text and "replay exact" in text
    assert paths["html"].stat().st_size < 400_000
    junit = ET.parse(paths["junit"]).getroot()
    failure = junit.find(".//testcase[@name='no_hard_violation']/failure")
    clips = report["sessions"][0]["film"]["clips"]
    (still,) = [c["still"] for c in clips if "hard_violation" in c["kinds"]]
    assert failure.get("message").endswith(f"still frame: {still}")
    assert (out / still).is_file()
    attachment = junit.find(".//testcase[@name='no_hard_violation']/system-out").text
    assert attachment == f"[[ATTACHMENT|{still}]]"
    saved = json.loads(paths["json"].read_text())
    assert all(
        c["video"].startswith("film/seed0000/") for c in saved["sessions"][0]["film"]["clips"]
    )


def test_a_deterministic_policy_replays_exactly_from_a_kept_checkpoint(tmp_path, arm3):
    """The shipped kind of policy (an MLP, no state outside the checkpoint): clips past the
    first kept checkpoint start from it, and reproduce the run bit for bit."""
    if not egl_works():
        pytest.skip("no EGL OpenGL context here (MUJOCO_GL=egl): the film cannot be rendered")
    from sim2real.eval.film.render import film_campaign
    from tests.test_soak import tiny_policy

    faults = FaultRanges(
        mean_interval=8.0,
        warmup=5.0,
        kinds=("push", "nan-action"),
        push_force=(1500.0, 3000.0),
        push_duration=(0.3, 0.6),
        nan_ticks=(12, 20),
    )
    config = SessionConfig(
        robot="arm3",
        policy=str(tiny_policy(tmp_path / "tiny.onnx", arm3)),
        seed=1,
        hours=60.0 / 3600.0,
        checkpoint_minutes=0.25,
        curve_seconds=10.0,
        ranges=SessionRanges(faults=faults),
    )
    results = run_campaign(config, 1, tmp_path / "soak", progress=False, recorders=(FilmRecorder,))
    # two clips: the first hard violation's (from the start) and one past the 30-s checkpoint
    (result,) = film_campaign(config, results, tmp_path / "soak", **LOOK)
    late = [c for c in result["film"]["clips"] if c["from_tick"] > 0]
    assert late and all(c["start_s"] >= c["from_tick"] * arm3.control_period for c in late)
    assert all(c["replay_exact"] is True and c["checked"] >= 1 for c in late)


def _browser():
    """(chromium, chromedriver) paths, or a skip naming what is missing."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        pytest.skip("selenium is not installed (extra 'dev')")
    browser = next(
        (shutil.which(n) for n in ("chromium", "chromium-browser") if shutil.which(n)), None
    )
    driver = shutil.which("chromedriver")
    if browser is None or driver is None:
        pytest.skip(
            "no Chromium here (apt-get install chromium chromium-driver; .ci/run installs them)"
        )
    return browser, driver


@ON_ONE_WORKER
def test_the_clip_loads_and_plays_in_headless_chromium(filmed):
    browser, driver = _browser()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    _, _, paths, _ = filmed
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"):
        options.add_argument(arg)
    chrome = webdriver.Chrome(service=Service(driver), options=options)
    try:
        chrome.set_script_timeout(30)
        chrome.get(Path(paths["html"]).resolve().as_uri())
        state = chrome.execute_async_script(
            """
            const done = arguments[arguments.length - 1];
            const v = document.querySelector("figure.clip[data-kind='hard_violation'] video");
            const report = (extra) => done(Object.assign({
                readyState: v.readyState, width: v.videoWidth, height: v.videoHeight,
                duration: v.duration, time: v.currentTime, paused: v.paused,
                error: v.error && v.error.code}, extra));
            const t0 = Date.now();
            const wait = () => (v.currentTime > 0.2 || Date.now() - t0 > 10000)
                ? report({}) : setTimeout(wait, 50);
            const play = () => v.play().then(wait).catch((e) => report({rejected: String(e)}));
            v.addEventListener("error", () => report({}), true);
            if (v.readyState >= 2) play(); else v.addEventListener("loadeddata", play);
            """
        )
    finally:
        chrome.quit()
    assert state.get("error") is None and "rejected" not in state, state
    assert state["readyState"] >= 2 and (state["width"], state["height"]) == (240, 180)
    assert state["duration"] > 3.0 and state["time"] > 0.2 and not state["paused"]


def test_no_film_keeps_no_checkpoints_and_renders_nothing(tmp_path, arm3):
    from sim2real.eval import cli

    policy = adversarial_onnx(tmp_path, arm3, "velocity")
    out = tmp_path / "soak"
    argv = ["--policy", str(policy), "--hours", "0.001", "--out", str(out), "--no-progress"]
    argv += ["--checkpoint-minutes", "0.02", "--min-success", "0", "--min-window-success", "0"]
    cli.main([*argv, "--max-interventions", "1", "--no-film"])
    report = json.loads((out / "report.json").read_text())
    assert "film" not in report["sessions"][0]
    assert not (out / "film").exists() and not retain_dir(out, 0).exists()
    assert "Film: the worst moments" not in (out / "report.html").read_text()
