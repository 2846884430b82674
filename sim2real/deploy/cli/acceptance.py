"""Acceptance run of the runtime: the adversarial policy against every limit, per robot and mode.

The runtime must be safe whatever the policy outputs. This runs the adversarial policy
(:mod:`sim2real.deploy.policy.adversarial`: uniform random actions in [-1, 1] with bursts of NaN) through
the full
runtime for a span of simulated time, records every command that reaches the plant, and checks:

- every command is finite (the plant never sees NaN or inf);
- position mode: every command lies within the hard position limits, and its finite-difference
  velocity, acceleration and jerk within the robot's limits;
- velocity mode: every command within the velocity limit, its rate of change within the
  acceleration limit and its second difference within the jerk limit;
- torque mode: every command within the effort limit and its rate within the smoother's torque
  rate limit;
- the joints themselves stay within the hard position limits (torque mode: within
  ``TORQUE_OVERSHOOT`` rad, the guard can only brake a moving joint);
- the runtime ends as the fault table says: RUNNING, a safe stop (SAFE_STOP, latched FAULTED)
  caused by a predicted hard-limit crossing, or an over-temperature safe stop (random torques
  heat the windings) that waits for them to cool.

Usage (the 10-minute runs of the runtime issue)::

    python -m sim2real.deploy.cli.acceptance --seconds 600            # arm3 and arm6, every control mode
    python -m sim2real.deploy.cli.acceptance --robot arm6 --mode torque --seconds 60
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import onnx

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.policy.adversarial import adversarial_model
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.rig.rig import Rig
from sim2real.deploy.runtime import Runtime
from sim2real.deploy.smoothing import TORQUE_RISE_TIME
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.robots import CONTROL_MODES, Robot, load_robot

#: Torque mode: largest tolerated excursion beyond a hard limit, rad (the guard brakes at the
#: effort limit; the joint's momentum carries it a little further).
TORQUE_OVERSHOOT = 0.01
#: Relative and absolute tolerance of the limit checks (floating-point round-off of Ruckig).
TOLERANCE = 1e-6


class RecordingBackend:
    """Wraps a backend and keeps every command written to it and the true joint angles after each
    advance: ``commands`` and ``true_q``, arrays shaped (ticks so far, envs, n).

    The buffers are preallocated for ``ticks`` and doubled when full (no allocation per tick).

    Raises:
        AssertionError: a non-finite command was written (it is not forwarded).
    """

    def __init__(self, backend, ticks: int = 1024):
        self.backend = backend
        shape = (max(ticks, 1), backend.envs, backend.n_joints)
        self._commands = np.zeros(shape)
        self._true_q = np.zeros(shape)
        self.n_commands = 0
        self.n_advances = 0

    def __getattr__(self, name):
        return getattr(self.backend, name)

    @property
    def commands(self) -> np.ndarray:
        return self._commands[: self.n_commands]

    @property
    def true_q(self) -> np.ndarray:
        return self._true_q[: self.n_advances]

    def write(self, command):
        assert np.isfinite(command).all(), "a non-finite command reached the backend"
        self._commands = _room(self._commands, self.n_commands)
        self._commands[self.n_commands] = command
        self.n_commands += 1
        self.backend.write(command)

    def advance(self):
        self.backend.advance()
        self._true_q = _room(self._true_q, self.n_advances)
        self._true_q[self.n_advances] = self.backend.true_position()
        self.n_advances += 1


def _room(buffer: np.ndarray, used: int) -> np.ndarray:
    """``buffer`` with room for one more row (twice as long when full)."""
    if used < len(buffer):
        return buffer
    grown = np.zeros((2 * len(buffer), *buffer.shape[1:]))
    grown[:used] = buffer
    return grown


@dataclass
class AcceptanceResult:
    """Outcome of one acceptance run; ``failures`` is empty when every check holds."""

    robot: str
    mode: str
    seconds: float
    wall_seconds: float
    non_finite_actions: int
    final_state: list[str]
    final_cause: list[str | None]
    max_overshoot: float
    worst_ratio: dict[str, float] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.failures


def finite_differences(commands: np.ndarray, dt: float, order: int) -> np.ndarray:
    """``order``-th finite difference of ``commands`` along axis 0, divided by ``dt**order``."""
    d = commands
    for _ in range(order):
        d = np.diff(d, axis=0) / dt
    return d


def check_adversarial(
    robot: Robot,
    mode: str,
    seconds: float,
    nan_probability: float = 0.05,
    seed: int = 0,
    workdir: Path | None = None,
) -> AcceptanceResult:
    """Run the adversarial policy for ``seconds`` of simulated time and check every limit.

    Args:
        robot: The robot. mode: Control mode ('position', 'velocity' or 'torque').
        seconds: Simulated time, s. nan_probability: NaN probability per call and env.
        seed: Seed of the plant's sensor streams. workdir: Where the ONNX file is written
            (default: a temporary folder).

    Returns:
        An :class:`AcceptanceResult`; ``result.failures`` names every check that failed.
    """
    rt, backend, wall = _run_adversarial(robot, mode, seconds, nan_probability, seed, workdir)
    cmds, true_q = backend.commands[:, 0], backend.true_q[:, 0]
    overshoot = np.maximum(true_q - robot.position_upper, 0) + np.maximum(
        robot.position_lower - true_q, 0
    )
    allowed = TORQUE_OVERSHOOT if mode == "torque" else 0.0
    failures: list[str] = []
    if overshoot.max() > allowed:
        failures.append(f"joints beyond the hard limits by up to {overshoot.max():.4f} rad")
    worst = _check_commands(robot, mode, cmds, rt.dt, failures)
    modes, causes = rt.mode_names(), rt.cause_names()
    failures += _check_runtime(rt, backend, nan_probability, modes, causes)
    return AcceptanceResult(
        robot=robot.name,
        mode=mode,
        seconds=rt.time,
        wall_seconds=wall,
        non_finite_actions=int(rt.counters.non_finite_actions.sum()),
        final_state=modes,
        final_cause=causes,
        max_overshoot=float(overshoot.max()),
        worst_ratio=worst,
        failures=failures,
    )


def _run_adversarial(
    robot: Robot,
    mode: str,
    seconds: float,
    nan_probability: float,
    seed: int,
    workdir: Path | None,
) -> tuple[Runtime, RecordingBackend, float]:
    """Return the runtime, its recording backend and the wall time of the adversarial run."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(workdir or tmp) / f"adversarial_{robot.name}_{mode}.onnx"
        spec = PolicySpec.for_robot(robot, mode=mode, position_range="hard")  # past soft limits
        onnx.save(adversarial_model(spec, nan_probability), path)
        policy = OnnxPolicy(path, robot)
    ticks = int(round(seconds / robot.control_period))
    backend = RecordingBackend(SimBackend(robot, mode=mode, seed=seed), ticks)
    rig = Rig(robot, policy, backend, envs=1)  # no task: the adversarial policy ignores goals
    rig.start()
    wall = time.perf_counter()
    rig.run(ticks)
    wall = time.perf_counter() - wall
    return rig.runtime, backend, wall


def _check_commands(
    robot: Robot, mode: str, cmds: np.ndarray, dt: float, failures: list[str]
) -> dict[str, float]:
    """Return the worst ratio to its limit of each command check; add the failed ones."""
    tol = TOLERANCE
    worst: dict[str, float] = {}

    def within(name: str, values: np.ndarray, limit: np.ndarray) -> None:
        ratio = float((np.abs(values) / limit).max()) if len(values) else 0.0
        worst[name] = ratio
        if np.any(np.abs(values) > limit * (1 + tol) + tol):
            failures.append(f"{name}: up to {ratio:.4f} x the limit")

    if mode == "position":
        centre = (robot.position_upper + robot.position_lower) / 2
        half = (robot.position_upper - robot.position_lower) / 2
        within("position command", cmds - centre, half)
        names = ("velocity", "acceleration", "jerk")
        limits = (robot.velocity_limit, robot.acceleration_limit, robot.jerk_limit)
        for order, (name, limit) in enumerate(zip(names, limits, strict=True), 1):
            within(f"command {name}", finite_differences(cmds, dt, order), limit)
    elif mode == "velocity":
        within("velocity command", cmds, robot.velocity_limit)
        names, limits = ("acceleration", "jerk"), (robot.acceleration_limit, robot.jerk_limit)
        for order, (name, limit) in enumerate(zip(names, limits, strict=True), 1):
            within(f"command {name}", finite_differences(cmds, dt, order), limit)
    else:
        within("torque command", cmds, robot.effort_limit)
        within("torque rate", np.diff(cmds, axis=0) / dt, robot.effort_limit / TORQUE_RISE_TIME)
    return worst


def _check_runtime(
    rt: Runtime,
    backend: RecordingBackend,
    nan_probability: float,
    modes: list[str],
    causes: list[str | None],
) -> list[str]:
    """Return the failures of the runtime's counters and of its final state and cause."""
    failures: list[str] = []
    if rt.counters.resyncs.sum():
        failures.append(f"the command stream was re-anchored {rt.counters.resyncs.sum()} times")
    if rt.counters.non_finite_actions.sum() == 0 and nan_probability > 0:
        failures.append("the policy never produced NaN: the NaN path was not exercised")
    hot = bool((backend.thermal.winding_temperature > rt.supervision.temp_start).any())
    if causes == ["over_temperature"]:
        # the random torques heated a winding past its maximum: a safe stop that resumes once
        # every winding is below the derating start (the fault table's thermal row)
        if modes[0] not in ("SAFE_STOP", "RAMP_IN") or not hot:
            failures.append(f"an over-temperature stop, but ended in {modes} with cool windings")
    elif rt.guard.totals()["hard_limit"] == 0:
        if modes != ["RUNNING"]:
            failures.append(f"ended in {modes} ({causes}) without a hard-limit violation")
    elif causes != ["hard_limit"] or modes[0] not in ("SAFE_STOP", "FAULTED"):
        failures.append(f"a hard-limit violation, but ended in {modes} ({causes})")
    return failures


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim2real.deploy.cli.acceptance",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--robot", action="append", default=None, help="arm3, arm6 (default: both)")
    p.add_argument("--mode", action="append", default=None, choices=CONTROL_MODES)
    p.add_argument("--seconds", type=float, default=600.0, help="simulated seconds per run")
    p.add_argument("--nan-probability", type=float, default=0.05)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    failed = 0
    for name in args.robot or ["arm3", "arm6"]:
        robot = load_robot(name)
        for mode in args.mode or list(CONTROL_MODES):
            r = check_adversarial(robot, mode, args.seconds, args.nan_probability, args.seed)
            failed += not r.passed
            ratios = ", ".join(f"{k} {v:.3f}" for k, v in r.worst_ratio.items())
            print(
                f"{'PASS' if r.passed else 'FAIL'} {r.robot} {r.mode:8s} {r.seconds:.0f} s "
                f"simulated in {r.wall_seconds:.0f} s: NaN actions {r.non_finite_actions}, "
                f"final {r.final_state[0]} ({r.final_cause[0]}), overshoot "
                f"{r.max_overshoot:.4f} rad; worst/limit: {ratios}"
            )
            for f in r.failures:
                print(f"     {f}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
