"""Compile the runtime's numba kernels into numba's on-disk cache, once, before the test workers
start.

Every kernel is compiled with ``cache=True``; on a fresh clone the cache is empty, and each
pytest-xdist worker would compile the same kernels at the same time. ``tests/conftest.py`` runs
this module in a subprocess from the xdist controller before the workers start; it builds and
ticks the runtime, the plant, the monitors and the task of a fixed-base arm in each control mode,
of the arm with a motion envelope and of a legged robot, with a policy that holds still.

Usage: ``python tests/warm_kernels.py`` (exit 0; a failure here fails nothing: the tests then
compile what they need themselves).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.monitors.interventions import InterventionMonitor
from sim2real.deploy.monitors.violations import ViolationMonitor
from sim2real.deploy.runtime import Runtime
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.deploy.tasks.task import task_for
from sim2real.robots import load_robot

#: (robot, control modes) whose stages are built and ticked.
ROBOTS = (
    ("arm3", ("velocity", "position", "torque")),
    ("arm6", ("position",)),
    ("go2", ("position",)),
)
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
    """Build and tick ``name``'s stages in control mode ``mode`` for :data:`TICKS` ticks."""
    robot = load_robot(name)
    spec = PolicySpec.for_robot(robot, mode=mode)
    backend = SimBackend(robot, mode=mode, envs=ENVS, seed=0)
    runtime = Runtime(robot, HoldStill(spec), backend)
    violations = ViolationMonitor(robot, ENVS)
    interventions = InterventionMonitor(runtime.guard, runtime.smoother)
    rngs = [np.random.default_rng(e) for e in range(ENVS)]
    task = task_for(robot, ENVS, backend, period=1.0, rng=rngs, interventions=interventions)
    task.reset(runtime, np.ones(ENVS, dtype=bool))
    runtime.start()
    interventions.resync()

    def on_tick(rt):
        violations.update(backend)
        interventions.update()
        task(rt)

    runtime.run(TICKS, on_tick=on_tick)


def main() -> int:
    for name, modes in ROBOTS:
        for mode in modes:
            warm(name, mode)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
