"""``deploy-run --viewer``: MuJoCo's interactive passive viewer on the running robot.

The runtime is the same as without it: the viewer only draws. With the simulated plant it shows
env 0's own ``MjModel`` and ``MjData`` (``mujoco.viewer.launch_passive``) and is synced after
every tick, so it moves in lockstep with the simulated clock (as fast as the loop runs) or in
real time with ``--realtime``. With a servo bus (no plant) it draws the robot's MJCF posed from
the runtime's estimate. Closing the window ends the run as if its duration had passed.

The passive viewer opens a window through GLFW and needs a display: :func:`check_display`
refuses, in one line naming ``DISPLAY`` and ``MUJOCO_GL``, before anything starts.
"""

from __future__ import annotations

import os
import sys

from sim2real.robots.errors import Sim2RealError


class NoDisplayError(Sim2RealError, ValueError):
    """``--viewer`` where no window can be opened (bad input: exit code 3)."""


def check_display(environ=None) -> None:
    """Raise :class:`NoDisplayError` unless a window can be opened here.

    On Linux a window needs ``DISPLAY`` (X11) or ``WAYLAND_DISPLAY``; ``MUJOCO_GL=egl`` or
    ``osmesa`` are offscreen backends with no window at all.
    """
    environ = os.environ if environ is None else environ
    gl = environ.get("MUJOCO_GL", "").lower()
    if gl in ("egl", "osmesa"):
        raise NoDisplayError(
            f"--viewer: MUJOCO_GL={gl} renders offscreen only and opens no window; unset "
            "MUJOCO_GL (or MUJOCO_GL=glfw) on a machine with a display, or use --video"
        )
    if sys.platform.startswith("linux") and not (
        environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY")
    ):
        raise NoDisplayError(
            "--viewer: no display (DISPLAY is not set): the viewer opens a window; run it on a "
            "desktop or under X forwarding, or render offscreen with --video (MUJOCO_GL=egl)"
        )


class PassiveViewer:
    """Call after every tick (``viewer(rt)``); returns True once the window was closed.

    Args:
        robot: The :class:`~robots.Robot`.
        backend: The backend; a simulated plant's env 0 (``models[0]``, ``datas[0]``) is shown
            as it is, any other backend's robot is posed from the runtime's estimate.

    Raises:
        NoDisplayError: no display (:func:`check_display`).
    """

    def __init__(self, robot, backend):
        import mujoco
        import mujoco.viewer

        from sim2real.deploy.core.backend import SimulatedPlant

        check_display()
        self.mj = mujoco
        if isinstance(backend, SimulatedPlant):
            self.model, self.data = backend.models[0], backend.datas[0]
            self.qpos_adr = None
        else:
            self.model = mujoco.MjModel.from_xml_path(str(robot.mjcf_path))
            self.data = mujoco.MjData(self.model)
            self.qpos_adr = [self.model.joint(n).qposadr[0] for n in robot.joint_names]
        self.handle = mujoco.viewer.launch_passive(
            self.model, self.data, show_left_ui=False, show_right_ui=False
        )

    def __call__(self, rt) -> bool:
        if not self.handle.is_running():
            return True
        if self.qpos_adr is not None:
            self.data.qpos[self.qpos_adr] = rt.state.q[0]
            self.mj.mj_kinematics(self.model, self.data)
        self.handle.sync()
        return False

    def close(self) -> None:
        self.handle.close()


def exit_now(code: int) -> None:
    """End the process with ``code`` without the interpreter's teardown (standard streams
    flushed): the passive viewer's thread can crash destroying its GLX context at exit (X error
    GLXBadContext/GLXBadDrawable, then SIGSEGV: google-deepmind/mujoco#1138, often under Xvfb),
    which would replace the run's exit code by 139."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
