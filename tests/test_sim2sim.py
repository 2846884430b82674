"""Sim-to-sim reports (sim2real/eval/sim2sim): compare, the files written, the sim2sim command.

The soak outputs compared here are real short MuJoCo soaks (arm3 with the shipped arm policy, go2
with the shipped go2 policy) run twice with the same seeds under two engine names: identical
results, so every gap is 0 until a test edits a copy of a report.json.
"""

import json
import shutil
import sys
from pathlib import Path

import pytest

from sim2real.eval import cli as soak_cli
from sim2real.eval.sim2sim import cli
from sim2real.eval.sim2sim.compare import (
    COUNT_MAX_RATIO,
    INTERVENTIONS_MAX_GAP_PP,
    PEAK_WINDING_MAX_GAP_C,
    SPEED_MAX_GAP_M_S,
    TRACKING_MAX_GAP_PP,
    VERDICT_DEPENDS,
    VERDICT_SAME,
    Sim2SimError,
    compare,
)
from sim2real.eval.sim2sim.write import markdown, write_sim2sim

REPO = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.xdist_group("sim2sim")

ARM_FIGURES = [
    "goals_reached",
    "violations.hard_limit",
    "violations.soft_limit",
    "violations.velocity",
    "violations.effort",
    "violations.workspace",
    "violations.self_collision",
    "interventions",
    "peak_winding",
    "safe_stops",
    "latched_faults",
    "diverged",
]


def shipped_onnx(name: str, tmp_path_factory) -> Path:
    """policies/NAME.onnx as ``make export`` writes it; exported here from policies/NAME.pt in a
    fresh clone (ONNX files are built, not committed)."""
    path = REPO / "sim2real" / "policies" / f"{name}.onnx"
    if path.is_file():
        return path
    from tests.runtime_fixtures import shipped_onnx as exported

    return exported(name, tmp_path_factory.mktemp(name))  # once per process


def soak(out: Path, robot: str, policy: Path, hours: str, sessions: int, *extra: str) -> Path:
    """A real soak-test campaign (MuJoCo) into ``out``; its report.json must exist."""
    argv = ["--robot", robot, "--policy", str(policy), "--hours", hours, "--seed", "0"]
    argv += ["--sessions", str(sessions), "--sessions-per-process", str(sessions)]
    argv += ["--out", str(out), "--no-progress", "--no-film", *extra]
    code = soak_cli.main(argv)
    assert code != soak_cli.EXIT_BAD_INPUT and (out / "report.json").is_file()
    return out


@pytest.fixture(scope="module")
def arm_soaks(tmp_path_factory) -> tuple[Path, Path]:
    """The same arm3 campaign (seeds 0 and 1, 18 simulated s each, faults every 4 s on average)
    run twice."""
    policy = shipped_onnx("arm", tmp_path_factory)
    root = tmp_path_factory.mktemp("arm_soaks")
    extra = ("--fault-interval", "4")
    return tuple(soak(root / name, "arm3", policy, "0.005", 2, *extra) for name in ("a", "b"))


@pytest.fixture(scope="module")
def go2_soaks(tmp_path_factory) -> tuple[Path, Path]:
    """The same go2 session (seed 0, 10.8 simulated s) run twice."""
    policy = shipped_onnx("go2", tmp_path_factory)
    root = tmp_path_factory.mktemp("go2_soaks")
    return tuple(soak(root / name, "go2", policy, "0.003", 1) for name in ("a", "b"))


def edited(src: Path, dest: Path, edit) -> Path:
    """A copy of soak folder ``src`` whose report.json ``edit(doc)`` changed."""
    shutil.copytree(src, dest)
    doc = json.loads((dest / "report.json").read_text())
    edit(doc)
    (dest / "report.json").write_text(json.dumps(doc))
    return dest


def by_name(figures: list[dict]) -> dict[str, dict]:
    return {f["name"]: f for f in figures}


# ---------------------------------------------------------------------- compare
def test_the_same_seeds_on_two_engine_names_are_the_same_on_both(arm_soaks):
    a, b = arm_soaks
    result = compare({"mujoco": a, "mujoco_again": b})
    assert result["verdict"] == VERDICT_SAME
    assert not result["engine_dependent"] and result["flagged"] == []
    assert result["engines"] == ["mujoco", "mujoco_again"] and result["kind"] == "arm"
    assert result["seeds"] == [0, 1] and result["robot"] == "arm3"
    assert result["reports"]["mujoco"]["engine"] == "mujoco"  # soak-test's campaign.engine
    assert result["warnings"][-1] == (
        "the reports of mujoco, mujoco_again were all run on engine 'mujoco': their gaps are "
        "not an engine's"
    )
    assert [f["name"] for f in result["totals"]] == ARM_FIGURES
    for figures in [result["totals"]] + [s["figures"] for s in result["sessions"]]:
        assert [f["name"] for f in figures] == ARM_FIGURES
        for f in figures:
            assert f["gap"] == 0 and f["relative_gap"] == 0, f
            assert f["values"]["mujoco"] == f["values"]["mujoco_again"]
            assert not f["engine_dependent"] and f["reason"] is None
    # the values are report.json's figures, in the documented units
    doc = json.loads((a / "report.json").read_text())
    t, totals = doc["totals"], by_name(result["totals"])
    assert totals["goals_reached"]["values"]["mujoco"] == 100 * t["goals"]["success_rate"]
    assert totals["goals_reached"]["notes"]["mujoco"] == (
        f"{t['goals']['reached']}/{t['goals']['issued']}"
    )
    assert (
        totals["interventions"]["values"]["mujoco"] == 100 * t["interventions"]["any"]["fraction"]
    )
    assert totals["peak_winding"]["values"]["mujoco"] == max(t["thermal"]["peak_c"].values())
    assert (
        totals["violations.workspace"]["values"]["mujoco"] == t["violations"]["total"]["workspace"]
    )
    stops = sum(s["runtime"]["safe_stops"] for s in doc["sessions"])
    assert totals["safe_stops"]["values"]["mujoco"] == stops
    assert totals["latched_faults"]["values"]["mujoco"] == t["latched_faults"]
    sessions = {s["seed"]: s for s in result["sessions"]}
    for s in doc["sessions"]:
        figures = by_name(sessions[s["seed"]]["figures"])
        assert sessions[s["seed"]]["ids"]["mujoco"] == s["id"]
        assert figures["peak_winding"]["values"]["mujoco"] == max(s["thermal"]["peak_c"].values())
        assert figures["goals_reached"]["values"]["mujoco"] == 100 * s["goals"]["success_rate"]
    assert any(s["faults"]["injected"] for s in doc["sessions"]), "the test needs faults"


def _peak(delta: float):
    def edit(doc):
        for section in (doc["totals"], doc["sessions"][0]):
            peaks = section["thermal"]["peak_c"]
            for joint in peaks:
                peaks[joint] += delta

    return edit


def _goals(lost: int):
    def edit(doc):
        for section in (doc["totals"], doc["sessions"][0]):
            g = section["goals"]
            g["reached"] -= lost
            g["success_rate"] = g["reached"] / g["issued"]

    return edit


def _violations(kind: str, ticks: int):
    def edit(doc):
        for section in (doc["totals"], doc["sessions"][0]):
            section["violations"]["total"][kind] = ticks

    return edit


def _interventions(points: float):
    def edit(doc):
        for section in (doc["totals"], doc["sessions"][0]):
            section["interventions"]["any"]["fraction"] += points / 100

    return edit


def _latched(doc):
    doc["totals"]["latched_faults"] = 1
    doc["sessions"][0]["runtime"]["latched_faults"] = 1


def _safe_stop(cause: str):
    def edit(doc):
        runtime = doc["sessions"][0]["runtime"]
        runtime["safe_stops"] += 1
        runtime["by_cause"][cause] += 1

    return edit


@pytest.mark.parametrize(
    "figure, edit, where",
    [
        ("peak_winding", _peak(PEAK_WINDING_MAX_GAP_C + 0.5), ["totals", "seed 0"]),
        ("goals_reached", _goals(2), ["totals", "seed 0"]),
        ("violations.workspace", _violations("workspace", 3), ["totals", "seed 0"]),
        ("violations.self_collision", _violations("self_collision", 1), ["totals", "seed 0"]),
        ("interventions", _interventions(INTERVENTIONS_MAX_GAP_PP + 0.1), ["totals", "seed 0"]),
        ("latched_faults", _latched, ["totals", "seed 0"]),
        ("safe_stops", _safe_stop("over_temperature"), ["totals", "seed 0"]),
    ],
)
def test_a_figure_edited_beyond_its_threshold_is_flagged_by_name(
    arm_soaks, tmp_path, figure, edit, where
):
    a, b = arm_soaks
    c = edited(b, tmp_path / "c", edit)
    result = compare({"mujoco": a, "pybullet": c})
    assert result["engine_dependent"] and result["dependent_figures"] == [figure]
    assert [f["where"] for f in result["flagged"]] == where
    label = by_name(result["totals"])[figure]["label"]
    assert result["verdict"] == f"{VERDICT_DEPENDS}: {label}"
    assert by_name(result["sessions"][1]["figures"])[figure]["engine_dependent"] is False


def test_gaps_within_the_thresholds_are_not_flagged(arm_soaks, tmp_path):
    a, b = arm_soaks

    def edit(doc):
        _peak(PEAK_WINDING_MAX_GAP_C - 0.5)(doc)
        _interventions(INTERVENTIONS_MAX_GAP_PP - 0.1)(doc)

    c = edited(b, tmp_path / "c", edit)
    result = compare({"mujoco": a, "pybullet": c})
    assert result["verdict"] == VERDICT_SAME, result["flagged"]
    peak = by_name(result["totals"])["peak_winding"]
    assert peak["gap"] == pytest.approx(PEAK_WINDING_MAX_GAP_C - 0.5)
    assert peak["relative_gap"] == pytest.approx(peak["gap"] / peak["values"]["pybullet"])


def test_counts_on_both_engines_are_flagged_beyond_an_order_of_magnitude(arm_soaks, tmp_path):
    a, b = arm_soaks
    within = int(COUNT_MAX_RATIO)
    a2 = edited(a, tmp_path / "a2", _violations("workspace", 1))
    b2 = edited(b, tmp_path / "b2", _violations("workspace", within))
    assert compare({"x": a2, "y": b2})["verdict"] == VERDICT_SAME
    b3 = edited(b, tmp_path / "b3", _violations("workspace", within + 1))
    result = compare({"x": a2, "y": b3})
    assert result["dependent_figures"] == ["violations.workspace"]
    assert f"more than {COUNT_MAX_RATIO:g} times" in result["flagged"][0]["reason"]


def test_the_legged_figures(go2_soaks, tmp_path):
    """go2: tracking success, falls and mean forward speed instead of goals."""
    a, b = go2_soaks
    result = compare({"mujoco": a, "other": b})
    assert result["kind"] == "legged" and result["verdict"] == VERDICT_SAME
    names = [f["name"] for f in result["totals"]]
    assert names[:3] == ["tracking_success", "falls", "mean_speed"] and "goals_reached" not in names
    doc = json.loads((a / "report.json").read_text())
    loco, totals = doc["totals"]["locomotion"], by_name(result["totals"])
    assert totals["tracking_success"]["values"]["mujoco"] == 100 * loco["tracking_success"]
    assert totals["mean_speed"]["values"]["mujoco"] == loco["mean_forward_speed_m_s"]
    assert totals["falls"]["values"]["mujoco"] == loco["falls"]

    def loco_edit(key, value):
        def edit(doc):
            for section in (doc["totals"], doc["sessions"][0]):
                section["locomotion"][key] = value(section["locomotion"][key])

        return edit

    cases = {
        "falls": loco_edit("falls", lambda v: v + 1),
        "tracking_success": loco_edit("tracking_success", lambda v: v - TRACKING_MAX_GAP_PP / 90),
        "mean_speed": loco_edit("mean_forward_speed_m_s", lambda v: v + 1.1 * SPEED_MAX_GAP_M_S),
    }
    for figure, edit in cases.items():
        c = edited(b, tmp_path / figure, edit)
        result = compare({"mujoco": a, "pybullet": c})
        assert result["dependent_figures"] == [figure], result["flagged"]
        assert [f["where"] for f in result["flagged"]] == ["totals", "seed 0"]
    never = edited(b, tmp_path / "never", loco_edit("tracking_success", lambda v: None))
    result = compare({"mujoco": a, "pybullet": never})
    flagged = result["flagged"][0]
    assert flagged["figure"] == "tracking_success"
    assert flagged["reason"] == "defined on mujoco only (not on pybullet)"


# ---------------------------------------------------------------------- errors
def test_a_missing_report_is_a_clear_error_naming_the_file(arm_soaks, tmp_path):
    a, _ = arm_soaks
    (tmp_path / "pybullet").mkdir()
    with pytest.raises(Sim2SimError) as err:
        compare({"mujoco": a, "pybullet": tmp_path / "pybullet"})
    assert isinstance(err.value, ValueError)
    assert str(err.value) == (
        f"{tmp_path / 'pybullet' / 'report.json'}: no report.json (expected the soak output of "
        f"engine 'pybullet': soak-test --engine pybullet --out {tmp_path / 'pybullet'})"
    )
    with pytest.raises(Sim2SimError, match="expected two engines or more"):
        compare({"mujoco": a})


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda d: d["totals"]["thermal"]["peak_c"].update(shoulder="hot"),
            "field 'totals.thermal.peak_c': expected an object of joint: degC (finite numbers), "
            "one joint at least, got {'shoulder': 'hot'",
        ),
        (
            lambda d: d["sessions"][1]["goals"].update(reached=-1),
            "field 'sessions[1].goals.reached': expected an integer >= 0, got -1",
        ),
        (
            lambda d: d["sessions"][0]["interventions"]["any"].update(fraction=1.5),
            "field 'sessions[0].interventions.any.fraction': expected a number in [0, 1], got 1.5",
        ),
        (
            lambda d: d["sessions"][0].pop("runtime"),
            "field 'sessions[0].runtime' is missing (expected it in a soak report.json)",
        ),
        (
            lambda d: d.update(schema_version=1),
            "field 'schema_version': expected 2, got 1",
        ),
        (
            lambda d: d["campaign"].update(policy_sha256="0" * 64),
            "field 'campaign.policy_sha256': expected '",
        ),
        (
            lambda d: d["sessions"][1].update(seed=7),
            "field 'sessions[].seed': expected the seeds [0, 1] as in mujoco's report",
        ),
        (
            lambda d: d["sessions"][1].update(seed=0),
            "field 'sessions[1].seed': expected a seed no other session has, got 0",
        ),
    ],
)
def test_a_malformed_field_is_a_clear_error_naming_file_and_field(
    arm_soaks, tmp_path, edit, message
):
    a, b = arm_soaks
    c = edited(b, tmp_path / "c", edit)
    with pytest.raises(Sim2SimError) as err:
        compare({"mujoco": a, "pybullet": c})
    assert str(err.value).startswith(f"{c / 'report.json'}: {message}"), str(err.value)


def test_invalid_json_names_the_file(arm_soaks, tmp_path):
    a, _ = arm_soaks
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "report.json").write_text('{"schema_version": 2,')
    with pytest.raises(Sim2SimError, match=r"b/report.json: not valid JSON"):
        compare({"mujoco": a, "pybullet": tmp_path / "b"})


# ---------------------------------------------------------------------- files
def test_the_files_written(arm_soaks, tmp_path):
    a, b = arm_soaks
    c = edited(b, tmp_path / "c", _peak(PEAK_WINDING_MAX_GAP_C + 5))
    result = compare({"mujoco": a, "pybullet": c})
    paths = write_sim2sim(tmp_path / "out", result)
    assert set(paths) == {"json", "md", "png"}
    assert json.loads(paths["json"].read_text()) == result
    md = paths["md"].read_text()
    assert md == markdown(result)
    assert "| figure | mujoco | pybullet | gap | flag |" in md
    row = next(line for line in md.splitlines() if line.startswith("| peak winding"))
    assert "**engine-dependent**: gap 15.0 degC > 10 degC" in row
    assert f"**Verdict: {VERDICT_DEPENDS}: peak winding temperature**" in md
    assert paths["png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "sim2sim.json",
        "sim2sim.md",
        "sim2sim.png",
    ]


def test_a_failed_write_leaves_the_previous_files(arm_soaks, tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    a, b = arm_soaks
    result = compare({"mujoco": a, "pybullet": b})
    out = tmp_path / "out"
    paths = write_sim2sim(out, result)
    before = {k: p.read_bytes() for k, p in paths.items()}

    def crash(self, fname, **kwargs):
        Path(fname).write_bytes(b"\x89PNG half")
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", crash)
    with pytest.raises(OSError, match="disk full"):
        write_sim2sim(out, {**result, "verdict": "changed"})
    assert paths["png"].read_bytes() == before["png"]
    assert not [p for p in out.iterdir() if p.suffix == ".part"]


# ---------------------------------------------------------------------- sim2sim
def test_cli_compare_only(arm_soaks, tmp_path, capsys):
    a, b = arm_soaks
    out = tmp_path / "out"
    shutil.copytree(a, out / "mujoco")
    shutil.copytree(b, out / "mujoco2")
    argv = ["--engines", "mujoco,mujoco2", "--out", str(out), "--compare-only"]
    assert cli.main(argv) == cli.EXIT_SAME
    printed = capsys.readouterr().out
    assert "| figure | mujoco | mujoco2 | gap | flag |" in printed
    assert f"sim2sim: {VERDICT_SAME}" in printed
    assert (out / "sim2sim.json").is_file() and (out / "sim2sim.png").is_file()

    shutil.rmtree(out / "mujoco2")
    edited(b, out / "mujoco2", _violations("hard_limit", 2))
    assert cli.main(argv) == cli.EXIT_ENGINE_DEPENDENT
    printed = capsys.readouterr().out
    assert f"sim2sim: {VERDICT_DEPENDS}: hard-limit violations" in printed
    assert "hard-limit violations (seed 0): 2 on mujoco2, none on mujoco" in printed


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--engines", "mujoco"], "--engines: expected two different engines or more"),
        (["--engines", "a,a"], "--engines: expected two different engines or more"),
        (["--engines", "a,../b"], "--engines: expected names of letters"),
        ([], "no report.json (expected the soak output of engine 'mujoco'"),
        (["--hours", "1"], None),
        (["--bogus"], "unrecognized arguments: --bogus"),
    ],
)
def test_cli_bad_input_exits_2_naming_it(tmp_path, capsys, argv, message):
    compare_only = argv != ["--hours", "1"]
    argv = [*argv, "--out", str(tmp_path / "out")] + (["--compare-only"] if compare_only else [])
    assert cli.main(argv) == cli.EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert err.startswith("sim2sim: error: ")
    assert (message or "--robot, --policy, --seed: required (unless --compare-only)") in err


def test_cli_refuses_its_own_options_after_the_separator(tmp_path, capsys):
    policy = REPO / "sim2real" / "policies" / "arm.pt"  # any file: refused before anything runs
    argv = ["--robot", "arm3", "--policy", str(policy), "--hours", "1", "--seed", "0"]
    argv += ["--out", str(tmp_path), "--", "--engine=mujoco"]
    assert cli.main(argv) == cli.EXIT_BAD_INPUT
    assert "--engine=mujoco: set by sim2sim for each engine" in capsys.readouterr().err


def test_soak_command_passes_the_options_through(tmp_path):
    options = "--robot go2 --policy p.onnx --hours 0.5 --seed 3 --sessions 2".split()
    args = cli._parser().parse_args([*options, "--out", str(tmp_path), "--no-film"])
    cmd = cli.soak_command(args, "pybullet", ["--fault-interval", "30"])
    assert cmd == [
        *(sys.executable, "-m", "sim2real.eval.cli", *options),
        *("--engine", "pybullet", "--out", str(tmp_path / "pybullet")),
        *("--no-film", "--fault-interval", "30"),
    ]


#: soak-test with every engine replaced by MuJoCo (``--engine mujoco``): the engine names are the
#: comparison's labels only, and the test does not depend on a second engine being installed.
ALL_MUJOCO = (
    sys.executable,
    "-c",
    "import sys\nfrom sim2real.eval.cli import main\nargv = sys.argv[1:]\n"
    "argv[argv.index('--engine') + 1] = 'mujoco'\nraise SystemExit(main(argv))",
)


def test_cli_runs_a_soak_per_engine_then_compares(tmp_path, capfd, monkeypatch, arm_soaks):
    """Each soak in its own process (its output on the file descriptors: capfd); a soak that
    fails a check (here: interventions) still wrote its report, and is compared."""
    monkeypatch.setattr(cli, "SOAK_COMMAND", ALL_MUJOCO)
    policy = json.loads((arm_soaks[0] / "report.json").read_text())["campaign"]["policy"]
    out = tmp_path / "out"
    argv = ["--robot", "arm3", "--policy", policy, "--hours", "0.002", "--seed", "4"]
    argv += ["--engines", "first,second", "--out", str(out), "--no-progress", "--no-film"]
    rest = ["--goal-period", "3", "--max-interventions", "0"]  # fails on any intervention
    assert cli.main([*argv, "--", *rest]) == cli.EXIT_SAME
    printed = capfd.readouterr().out
    assert printed.count(f"--engine first --out {out / 'first'}") == 1
    assert printed.count(f"--engine second --out {out / 'second'}") == 1
    assert f"sim2sim: {VERDICT_SAME}" in printed
    for engine in ("first", "second"):
        report = json.loads((out / engine / "report.json").read_text())
        assert report["campaign"]["session_options"]["goal_period"] == 3.0
        assert report["exit_code"] == soak_cli.EXIT_INTERVENTIONS
        assert [s["seed"] for s in report["sessions"]] == [4]
    result = json.loads((out / "sim2sim.json").read_text())
    assert result["engines"] == ["first", "second"] and result["seeds"] == [4]
    assert "warning: the reports of first, second were all run on engine 'mujoco'" in printed

    # a soak that writes no report (its bad input): its exit code, nothing compared
    (out / "sim2sim.json").unlink()
    code = cli.main([*argv, "--", "--goal-period", "-1"])
    assert code == soak_cli.EXIT_BAD_INPUT
    err = capfd.readouterr().err
    assert "--goal-period: expected a number > 0" in err
    assert f"sim2sim: soak-test on first wrote no report ({out / 'first' / 'report.json'}" in err
    assert not (out / "sim2sim.json").exists()
