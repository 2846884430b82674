"""deploy-run refuses bad input on its newer surfaces (an operator mapping, an operator source,
the Go2's velocity command, the Unitree backend's network interface) before anything opens: exit
3, one line on stderr naming the file or option and what was expected, and no file in the folder
the run's outputs (telemetry, report, recorded commands) were to go to.

stderr is captured at the file descriptor (capfd): Cyclone DDS writes there from C."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim2real.deploy.cli.deploy_run import EXIT_BAD_INPUT, deploy_run_main
from tests.runtime_fixtures import zero_action_onnx

ROOT = Path(__file__).resolve().parents[1]
SESSION = ROOT / "tests" / "data" / "operator" / "xbox_session.jsonl"


@pytest.fixture(scope="module")
def go2_still(go2, tmp_path_factory) -> Path:
    """An ONNX policy of the Go2's default spec whose action is 0 (no export needed)."""
    return zero_action_onnx(go2, tmp_path_factory.mktemp("refused") / "still.onnx")


def _refused(tmp_path: Path, capfd, *argv: str) -> str:
    """Run deploy-run with ``argv`` and its outputs in ``tmp_path/out``; assert it is refused
    (exit 3) with one stderr line and no file in ``out``; returns the line."""
    out = tmp_path / "out"
    out.mkdir()
    outputs = [
        "--telemetry", str(out / "run.mcap"), "--report", str(out / "run.json"),
        "--record-commands", str(out / "run.npz"),
    ]  # fmt: skip
    code = deploy_run_main([*argv, "--duration", "1", *outputs])
    err = capfd.readouterr().err
    assert code == EXIT_BAD_INPUT, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("deploy-run: error: "), err
    assert sorted(p.name for p in out.iterdir()) == []
    return lines[0]


def _operated(policy: Path, mapping: str, source: str) -> list[str]:
    return [
        "--robot", "go2", "--policy", str(policy), "--operator", mapping,
        "--operator-source", source,
    ]  # fmt: skip


def test_a_mapping_whose_blend_time_is_not_a_number_is_refused_in_one_line(
    tmp_path, capfd, go2_still
):
    mapping = tmp_path / "blend.toml"
    mapping.write_text('source = "evdev"\nblend_time = "0.5 s"\n[actions]\ndamp = "BTN_EAST"\n')
    line = _refused(tmp_path, capfd, *_operated(go2_still, str(mapping), f"evdev:{SESSION}"))
    assert f"operator mapping {mapping}: blend_time: Input should be a valid number" in line
    assert "(got '0.5 s')" in line


def test_a_mapping_with_an_unknown_button_is_refused_in_one_line(tmp_path, capfd, go2_still):
    mapping = tmp_path / "button.toml"
    mapping.write_text('source = "evdev"\n[actions]\ndamp = "BTN_EAST"\nstand = "START"\n')
    line = _refused(tmp_path, capfd, *_operated(go2_still, str(mapping), f"evdev:{SESSION}"))
    assert f"operator mapping {mapping}: actions.stand: 'START' is not an evdev button" in line
    assert "BTN_*, KEY_* or ABS_*" in line  # what it expected


def test_a_missing_recorded_evdev_stream_is_refused_in_one_line(tmp_path, capfd, go2_still):
    missing = tmp_path / "missing.jsonl"
    line = _refused(tmp_path, capfd, *_operated(go2_still, "xbox_evdev", f"evdev:{missing}"))
    assert f"--operator-source: evdev stream {missing}: cannot read it" in line
    assert "expected a recorded stream (JSON lines) or a device /dev/input/eventN" in line


def test_a_go2_command_of_two_numbers_is_refused_in_one_line(tmp_path, capfd, go2_still):
    line = _refused(
        tmp_path, capfd, "--robot", "go2", "--policy", str(go2_still), "--command", "0.5,0"
    )
    assert "--command '0.5,0': expected VX,VY,WZ" in line


def test_an_unknown_network_interface_is_refused_in_one_line_of_ours(tmp_path, capfd, go2_still):
    """Cyclone DDS printed a line of its own before ours: the interface is checked first."""
    pytest.importorskip("cyclonedds", reason="pip install '.[unitree]'")
    line = _refused(
        tmp_path, capfd, "--backend", "unitree", "--network-interface", "nosuchif0",
        "--domain-id", "231", "--robot", "go2", "--policy", str(go2_still),
    )  # fmt: skip
    assert "--network-interface 'nosuchif0': no such network interface" in line
    assert "expected one of" in line and "lo" in line


@pytest.mark.parametrize("stage", ["start", "run"])
def test_a_run_failing_after_its_outputs_opened_leaves_none_behind(
    tmp_path, capfd, go2_still, monkeypatch, stage
):
    """The safety net: an error once the telemetry and the hooks are open (the rig's start, as
    a refused --require-rt; the loop, as a bus lost) removes the telemetry's .part and writes
    no recorded commands."""
    from sim2real.deploy.rig.rig import Rig

    def fail(*_args):
        raise OSError(f"the {stage} failed (test)")

    monkeypatch.setattr(Rig, stage, fail)
    line = _refused(
        tmp_path, capfd, "--robot", "go2", "--policy", str(go2_still), "--command", "0.5,0,0"
    )
    assert line == f"deploy-run: error: the {stage} failed (test)"
