"""deploy-run --viewer: without a display it refuses in one line, before the run starts (the
viewer itself needs a window: not testable on a headless machine)."""

import sys

import pytest

from sim2real.deploy.cli.deploy_run import EXIT_BAD_INPUT, deploy_run_main
from sim2real.deploy.observe.viewer import NoDisplayError, check_display


@pytest.mark.parametrize(
    ("environ", "names"),
    [
        ({}, ("DISPLAY", "MUJOCO_GL")),
        ({"DISPLAY": ":0", "MUJOCO_GL": "egl"}, ("MUJOCO_GL=egl",)),
        ({"WAYLAND_DISPLAY": "wayland-0", "MUJOCO_GL": "osmesa"}, ("MUJOCO_GL=osmesa",)),
    ],
)
def test_no_window_is_refused_naming_the_variables(environ, names):
    with pytest.raises(NoDisplayError) as err:
        check_display(environ)
    assert all(n in str(err.value) for n in names) and "\n" not in str(err.value)


def test_a_display_is_accepted():
    check_display({"DISPLAY": ":0"})
    check_display({"WAYLAND_DISPLAY": "wayland-0", "MUJOCO_GL": "glfw"})


def test_deploy_run_viewer_without_display_exits_3_before_the_run(monkeypatch, capsys, tmp_path):
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL"):
        monkeypatch.delenv(name, raising=False)
    missing = tmp_path / "never_read.onnx"  # the run would fail on it: refused before that
    assert deploy_run_main(["--policy", str(missing), "--viewer"]) == EXIT_BAD_INPUT
    out, err = capsys.readouterr()
    assert err.count("\n") == 1 and err.startswith("deploy-run: error: --viewer: no display")
    assert "DISPLAY is not set" in err and "MUJOCO_GL=egl" in err
    assert out == "" and "never_read" not in err


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the EGL default is Linux's")
def test_video_chooses_egl_only_headless_and_unchosen():
    from sim2real.deploy.observe.video import headless_gl_default

    headless = {}
    assert headless_gl_default(headless) == "egl" and headless == {"MUJOCO_GL": "egl"}
    desktop = {"DISPLAY": ":0"}
    assert headless_gl_default(desktop) is None and "MUJOCO_GL" not in desktop
    chosen = {"MUJOCO_GL": "osmesa"}
    assert headless_gl_default(chosen) is None and chosen == {"MUJOCO_GL": "osmesa"}
