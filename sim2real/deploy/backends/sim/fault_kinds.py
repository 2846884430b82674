"""The fault kinds the simulated robot's injector applies (:data:`FAULT_KINDS`): each one
:class:`FaultKind`, registered under its name with what it does while it is in force.

A fault kind does its work in up to three places of a tick, each a function of the injector
(:class:`sim2real.deploy.backends.sim.faults.FaultInjector`), the fault
(:class:`~sim2real.deploy.backends.sim.faults.Fault`) and the envs it is on:

- ``plant(injector, fault, envs, force)``: before the plant is read (the backend's per-env sensor
  settings ``injector.backend.dropout_probability`` and ``latency_ticks``, reset to the settings
  without faults each tick; ``force`` (envs, 3) N, the forces the injector sets on the envs'
  bodies when ``forces``);
- ``frame(injector, fault, envs, frame)``: on the sensor frame read
  (:class:`~sim2real.deploy.core.backend.SensorFrame`; ``injector.frozen_frame(frame)`` is a copy
  kept while any frame fault is in force);
- ``action(injector, fault, envs, action)``: on the policy's action (envs, n).

Adding a fault kind is one module (or a few lines) calling :func:`register_fault_kind`; deploy-run's
``--inject KIND@...`` takes it at once. For the soak to draw it, register its draw too
(:func:`sim2real.eval.world.fault_draws.register_fault_draw`, the schedule's room): the test of the
seams names a kind with no draw (``tests/test_fault_registry.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim2real.deploy.core.registry import Registry

LATENCY_SPIKE_TICKS = 10  # control ticks (50 ms at 200 Hz)
PUSH_FORCE = 20.0  # N, a firm shove by hand
CABLE_FORCE = 10.0  # N, a moderate sustained pull (a cable or hose of about 1 kg)


@dataclass(frozen=True)
class FaultKind:
    """A fault kind (module docstring).

    Attributes:
        name: ``KIND`` of ``--inject KIND@SECONDS`` and of reports.
        doc: One line: what the fault does (deploy-run's help, the module docstring's list).
        plant: Hook before the plant is read, or None.
        frame: Hook on the sensor frame, or None.
        action: Hook on the policy's action, or None.
        forces: Its ``plant`` hook adds to ``force``: the injector then sets the envs' external
            forces every tick while its schedule holds such a fault.
        magnitude_unit: Unit of an optional ``=MAGNITUDE`` (``push=80@5``), or None: takes none.
        whole_magnitude: The magnitude is a whole number (control ticks).
    """

    name: str
    doc: str
    plant: Callable | None = None
    frame: Callable | None = None
    action: Callable | None = None
    forces: bool = False
    magnitude_unit: str | None = None
    whole_magnitude: bool = False


#: The fault kinds, by name (the built-in ones registered below, in this order).
FAULT_KINDS: Registry[FaultKind] = Registry("fault kind")


def register_fault_kind(kind: FaultKind) -> FaultKind:
    """Register ``kind`` under its name; returns it.

    Raises:
        ValueError: the name is taken, empty or has ``=@:`` in it (``--inject``'s separators), or
            the kind does nothing (no hook).
    """
    if not kind.name or any(c in kind.name for c in "=@:"):
        raise ValueError(f"fault kind {kind.name!r}: expected a name without '=', '@' or ':'")
    if kind.plant is None and kind.frame is None and kind.action is None:
        raise ValueError(f"fault kind '{kind.name}': expected a plant, frame or action hook")
    return FAULT_KINDS.register(kind.name, kind)


def fault_kind(name: str) -> FaultKind:
    """The kind named ``name``.

    Raises:
        ValueError: no such kind (the message lists the registered ones).
    """
    return FAULT_KINDS.get(name)


def cable_direction(backend, fault, env: int) -> np.ndarray:
    """Unit vector (3,) of a cable's pull: ``fault.direction``, or along env ``env``'s gravity.

    Raises:
        ValueError: a direction of no length.
    """
    if fault.direction is not None:
        d = np.asarray(fault.direction, dtype=np.float64)
    else:
        d = np.array(backend.models[env].opt.gravity, dtype=np.float64)
    norm = np.linalg.norm(d)
    if not norm > 0.0:
        raise ValueError(f"fault {fault}: the cable direction {d.tolist()} has no length")
    return d / norm


def _dropout(injector, fault, envs, force) -> None:
    injector.backend.dropout_probability[envs] = 1.0


def _latency(injector, fault, envs, force) -> None:
    b = injector.backend
    spike = int(fault.magnitude or LATENCY_SPIKE_TICKS)
    b.latency_ticks[envs] = np.minimum(injector.base_latency[envs] + spike, b.max_latency_ticks)


def _push(injector, fault, envs, force) -> None:
    force[envs, 0] = fault.magnitude or PUSH_FORCE


def _cable(injector, fault, envs, force) -> None:
    for e in envs:
        force[e] += (fault.magnitude or CABLE_FORCE) * cable_direction(injector.backend, fault, e)


def _stale(injector, fault, envs, frame) -> None:
    frozen = injector.frozen_frame(frame)
    frame.position[envs] = frozen.position[envs]
    frame.position_stamp[envs] = frozen.position_stamp[envs]
    if frame.velocity is not None and frozen.velocity is not None:
        frame.velocity[envs] = frozen.velocity[envs]


def _nan_action(injector, fault, envs, action) -> None:
    action[envs] = np.nan


register_fault_kind(
    FaultKind(
        "dropout",
        "every encoder reading is lost (the estimator must predict only, then stop safely when "
        "the data is stale longer than Robot.stale_limit)",
        plant=_dropout,
    )
)
register_fault_kind(
    FaultKind(
        "stale",
        "the sensor frame freezes: the same old readings with their old time stamps repeat",
        frame=_stale,
    )
)
register_fault_kind(FaultKind("nan-action", "the policy outputs NaN", action=_nan_action))
register_fault_kind(
    FaultKind(
        "latency",
        f"MAGNITUDE (default {LATENCY_SPIKE_TICKS}) extra control ticks of encoder latency",
        plant=_latency,
        magnitude_unit="control ticks",
        whole_magnitude=True,
    )
)
register_fault_kind(
    FaultKind(
        "push",
        f"a force of MAGNITUDE N (default {PUSH_FORCE:g}) along +X pushes the end effector (a "
        "floating base's base)",
        plant=_push,
        forces=True,
        magnitude_unit="N",
    )
)
register_fault_kind(
    FaultKind(
        "cable",
        f"a cable pulls on the end effector: a sustained force of MAGNITUDE N (default "
        f"{CABLE_FORCE:g}) along the fault's direction (world frame; default along gravity, a "
        "hanging load), usually for tens of seconds",
        plant=_cable,
        forces=True,
        magnitude_unit="N",
    )
)

#: The built-in kinds' names, in registration order (a kind registered later is in
#: ``FAULT_KINDS.names()``).
KINDS = FAULT_KINDS.names()
