"""Compile the runtime's numba kernels into numba's on-disk cache, once, before the test workers
start.

Every kernel is compiled with ``cache=True``; on a fresh clone the cache is empty, and each
pytest-xdist worker would compile the same kernels at the same time. ``tests/conftest.py`` runs
this module in a subprocess from the xdist controller before the workers start. It builds and
runs the run's one assembly (the ``Rig``: runtime, plant, monitors, task and ``deploy-run``'s
motion figures) of a fixed-base arm in each control mode, of the arm with a motion envelope and
of a legged robot, with a policy that holds still. The legged robot's kernels (the base
estimator's, the estimation monitor's, then its run) compile in a second process at the same
time as the arms' (``--legged``): the two share two cores where one process left one idle.

Usage: ``python tests/warm_kernels.py`` (exit 0; a failure here fails nothing: the tests then
compile what they need themselves).
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.rig.rig import MotionHook, Rig
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.robots import load_robot

#: (robot, control modes) whose runs are built and ticked by this process.
ARMS = (
    ("arm3", ("velocity", "position", "torque")),
    ("arm6", ("position",)),
)
#: The legged robot and its control mode, warmed by the second process.
LEGGED = ("go2", "position")
#: Robots per batch (kernels specialize on types, not sizes).
ENVS = 2
#: Ticks run per robot and mode.
TICKS = 60


class HoldStill:
    """A policy (``spec``, ``(envs, obs_dim) -> (envs, act_dim)``) that outputs zeros."""

    def __init__(self, spec: PolicySpec):
        self.spec = spec

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((obs.shape[0], self.spec.act_dim), dtype=np.float32)


def warm(name: str, mode: str) -> None:
    """Build ``name``'s run in control mode ``mode`` and tick it for :data:`TICKS` ticks."""
    robot = load_robot(name)
    spec = PolicySpec.for_robot(robot, mode=mode)
    backend = SimBackend(robot, mode=mode, envs=ENVS, seed=0)
    rngs = [np.random.default_rng(e) for e in range(ENVS)]
    rig = Rig(robot, HoldStill(spec), backend, envs=ENVS, task=dict(period=1.0, rng=rngs))
    rig.add(MotionHook(rig))
    rig.start()
    rig.run(TICKS)


def warm_legged() -> None:
    """The legged robot's own kernels first (its base estimator's and its estimation monitor's,
    which no arm shares), then its run (by then mostly loaded from the arms' process)."""
    from sim2real.deploy.estimation.base import BaseStateEstimator
    from sim2real.deploy.monitors.estimation import EstimationMonitor

    name, mode = LEGGED
    robot = load_robot(name)
    BaseStateEstimator(robot, ENVS)
    EstimationMonitor(robot, ENVS)
    warm(name, mode)


def main(argv: list[str]) -> int:
    if argv == ["--legged"]:
        warm_legged()
        return 0
    legged = subprocess.Popen([sys.executable, __file__, "--legged"])
    try:
        for name, modes in ARMS:
            for mode in modes:
                warm(name, mode)
    finally:
        legged.wait()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
