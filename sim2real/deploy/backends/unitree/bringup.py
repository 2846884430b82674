"""The bring-up of a Unitree robot, stage by stage, each printed as it starts:
:func:`bring_up`, run by :meth:`sim2real.deploy.backends.unitree.backend.UnitreeBackend.open`.

1. **LowState**: wait up to ``lowstate_timeout`` for a complete state; none is a
   :class:`BringupError` naming the interface and the domain, and what to check.
2. **mode_machine**: the robot's (``unitree_hg``), echoed; every command carries it.
3. **sport mode**: the motion switcher's active mode (:mod:`.motion_switcher`); one still active
   is a :class:`BringupError` saying how to release it. No answer is a printed note: the check
   needs the service (robots and firmwares without it, a bridge without it).
4. **damping** for ``DAMPING_TIME`` (kp 0, the damping kd): the robot settles where it lies.
5. **ramp** from the measured pose to the home pose in ``[unitree] ramp_time`` (linear in time,
   as unitree_rl_gym's ``deploy_real`` moves to its default pose) with ``[unitree] ramp_kp`` /
   ``ramp_kd`` and ``SETTLE_TIME`` at home, then until at rest (``REST_TIMEOUT`` at most). A
   joint farther than ``RAMP_TOLERANCE`` from home then is a :class:`BringupError`.

A LowState silent for ``BRINGUP_STALE`` during stages 4-5 stops the bring-up (damping, then a
:class:`BringupError`). The backend then holds the home pose at the ramp's gains until the
runtime's first command, keeps them through the runtime's RAMP_IN, and from the policy's first
command hands over to the joints' kp/kd over ``BLEND_TIME`` (:mod:`.handover`: without a jump,
and a soft policy PD never holds the robot without its policy: a G1 sagged to the floor).
"""

from __future__ import annotations

import time

import numpy as np

from sim2real.deploy.backends.unitree.family import TOPIC_LOWSTATE
from sim2real.deploy.backends.unitree.motion_switcher import RELEASE_HINT, check_mode
from sim2real.deploy.core.modes import REST_SPEED
from sim2real.robots.errors import Sim2RealError

#: s ``open()`` waits for the first complete LowState (default of ``--lowstate-timeout``).
LOWSTATE_TIMEOUT = 5.0
#: s of damping before the ramp (our choice).
DAMPING_TIME = 1.0
#: s at the home pose after the ramp, at the ramp's gains, before the check (our choice).
SETTLE_TIME = 0.3
#: s the robot may take after ``SETTLE_TIME`` to come to rest at home (our choice), checked
#: every ``REST_CHECK`` s against the runtime's ``REST_SPEED`` (rad/s).
REST_TIMEOUT = 2.0
REST_CHECK = 0.05
#: s after the policy's first command over which the ramp's gains blend into the joints' (our
#: choice).
BLEND_TIME = 0.5
#: rad: a joint farther from home after the ramp did not follow the commands (our choice: above
#: a leg's sag under the robot's weight at the ramp's gains, below a lying leg's distance).
RAMP_TOLERANCE = 0.3
#: s without a LowState that stops the bring-up (our choice).
BRINGUP_STALE = 0.5
#: s the motion switcher has to answer.
SPORT_MODE_TIMEOUT = 2.0


class BringupError(Sim2RealError, OSError):
    """The robot cannot be brought up: no LowState, a high-level mode active, commands not
    followed. The message says what to check."""


def bring_up(b) -> None:
    """Stages 1-5 of the module docstring on the opened backend ``b``
    (:class:`~sim2real.deploy.backends.unitree.backend.UnitreeBackend`).

    Raises:
        BringupError: see the module docstring; the robot is damped when it was commanded.
    """
    where = f"interface {b.interface or '(Cyclone DDS default)'}, DDS domain {b.domain_id}"
    b.log(f"[1/5] waiting for LowState on {TOPIC_LOWSTATE} ({where}, {b.family.name})")
    _wait_for_state(b, where)
    b.log(
        f"[2/5] LowState arriving; mode_machine {b.mode_machine}, echoed in every command"
        if b.family.has_mode_machine
        else "[2/5] LowState arriving (unitree_go: no mode_machine; head 0xFE 0xEF, level 0xFF)"
    )
    b.log("[3/5] asking the motion switcher for an active high-level mode")
    if b.check_sport_mode:
        mode = check_mode(b._link, SPORT_MODE_TIMEOUT)
        if mode is None:
            b.log(
                "      no motion switcher answered: make sure no high-level controller (sport "
                "mode) commands the motors"
            )
        elif mode.get("name"):
            raise BringupError(
                f"the robot reports the high-level motion mode '{mode['name']}' active ({where}):"
                f" {RELEASE_HINT}"
            )
        else:
            b.log("      none active")
    else:
        b.log("      skipped (--skip-sport-mode-check)")
    b.log(f"[4/5] damping for {DAMPING_TIME:g} s (kp 0, kd {_kd(b)})")
    b._damping = True
    _run(b, DAMPING_TIME, lambda t: b._hold_target)
    q0 = _pose(b)
    home = b._hold_target
    ramp = b.config.ramp_time
    legs = ~b.robot.velocity_driven  # a wheel takes speed 0, no pose: its angle is any
    far = float(np.abs(home - q0)[legs].max())
    b.log(f"[5/5] ramp to the home pose over {ramp:g} s (farthest joint {far:.2f} rad away)")
    b._damping = False
    _run(b, ramp, lambda t: q0 + min(1.0, t / ramp) * (home - q0), (b.ramp_kp, b.ramp_kd))
    _run(b, SETTLE_TIME, lambda t: home, (b.ramp_kp, b.ramp_kd))
    rest = _settle(b, home)
    q = _pose(b)
    off = np.where(legs, np.abs(q - home), 0.0)
    if off.max() > RAMP_TOLERANCE:
        j = int(off.argmax())
        b._damping = True
        raise BringupError(
            f"the robot did not follow the ramp to its home pose: {b.names[j]} (motor "
            f"{int(b.slots[j])}) is at {q[j]:.3f} rad, home {home[j]:.3f} rad ({where}); are "
            "the commands refused (a CRC the robot rejects, a motor mode it does not take: "
            "robot.toml [unitree] motor_mode), or does another controller command the motors?"
        )

    b.log(
        f"      at home, at rest {SETTLE_TIME + rest:.2f} s after the ramp; holding it until the "
        "policy starts, then blending into its gains over "
        f"{BLEND_TIME:g} s"
    )


def _settle(b, home: np.ndarray) -> float:
    """Hold ``home`` at the ramp's gains until the drives report every joint slower than the
    runtime's ``REST_SPEED``, at most ``REST_TIMEOUT`` s (then on, printed): the runtime's
    RAMP_IN ends at rest, and a robot handed over still swinging from the ramp stood for seconds
    before its policy could start. Returns the s held."""
    start = time.monotonic()
    while (held := time.monotonic() - start) < REST_TIMEOUT:
        frame = _run(b, REST_CHECK, lambda t: home, (b.ramp_kp, b.ramp_kd))
        v = frame.velocity
        if v is None or (np.isfinite(v[0]).any() and np.nanmax(np.abs(v[0])) < REST_SPEED):
            return held
    b.log(f"      not at rest after {REST_TIMEOUT:g} s at home: handing over anyway")
    return held


def _kd(b) -> str:
    kd = np.unique(b.damping_kd)
    return f"{kd[0]:g}" if len(kd) == 1 else f"{kd.min():g}-{kd.max():g}"


def _wait_for_state(b, where: str) -> None:
    end = time.monotonic() + b.lowstate_timeout
    while time.monotonic() < end:
        frame = b.read()
        if not np.isnan(frame.position).any():
            return
        time.sleep(0.01)
    heard = (
        f"{b.received} LowState samples arrived, none complete and valid (dropouts "
        f"{dict(b.dropouts)})"
        if b.received
        else "none arrived"
    )
    if b.received and b.zero_crc == b.dropouts["bad_crc"] == b.received:
        raise BringupError(
            f"no valid LowState on {TOPIC_LOWSTATE} within {b.lowstate_timeout:g} s ({where}): "
            f"all {b.received} samples carry crc 0, as Unitree's simulation bridges "
            "(unitree_mujoco) publish them; for a simulator pass --lowstate-unchecked (never "
            "for a robot: a real robot fills its CRC)"
        )
    raise BringupError(
        f"no LowState on {TOPIC_LOWSTATE} within {b.lowstate_timeout:g} s ({where}): {heard}. "
        "Is the robot on, this computer on its network (the Go2's is 192.168.123.0/24; `ip addr` "
        "names the interface its cable is in: --network-interface), and the domain the robot's "
        "(0 on the robots, 1 in Unitree's simulation bridges: --domain-id)?"
    )


def _pose(b) -> np.ndarray:
    """The newest complete measured pose (reads until one arrives, ``BRINGUP_STALE`` at most)."""
    end = time.monotonic() + BRINGUP_STALE
    while True:
        frame = b.read()
        if not np.isnan(frame.position).any():
            return frame.position[0].copy()
        if time.monotonic() > end:
            b._damping = True
            raise BringupError(f"LowState stopped during the bring-up (dropouts {b.dropouts})")
        time.sleep(0.005)


def _run(b, seconds: float, target, gains=None):
    """Send ``target(t)`` (rad, (n,)) every control period for ``seconds``, reading the states:
    damping while the backend damps, else a position target with ``gains`` ((kp, kd), or a
    function of ``t`` returning them). A LowState silent for ``BRINGUP_STALE`` stops it
    (damping, :class:`BringupError`). Returns the last frame read (None if none was)."""
    start = time.monotonic()
    last = start
    t = 0.0
    frame = None  # no period to run (``seconds`` <= 0): none read
    while t < seconds:
        frame = b.read()
        now = time.monotonic()
        if not np.isnan(frame.position).all():
            last = now
        elif now - last > BRINGUP_STALE:
            b._damping = True
            b._send(b._hold_target)
            raise BringupError(
                f"LowState stopped during the bring-up ({now - last:.2f} s without one; dropouts "
                f"{dict(b.dropouts)})"
            )
        kp_kd = gains(t) if callable(gains) else gains
        b._send(np.asarray(target(t)), *(kp_kd or ()))
        t += b.period
        time.sleep(max(0.0, start + t - time.monotonic()))
    return frame
