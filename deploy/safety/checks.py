"""The guard's checks: one list that the guard's counters, the compiled kernel's count rows and
the intervention monitor's names all come from.

A check here is what :meth:`deploy.safety.guard.SafetyGuard.filter` counts when it changes a
target (an intervention). Its row in ``SafetyGuard.count_matrix`` is its index in
:data:`GUARD_CHECKS`; the kernel (:mod:`deploy.safety.kernel`) and the numpy reference take their
row numbers from :func:`row`, so adding a check is one entry here plus its code in the guard's two
paths (their outputs are compared by the guard's tests, check by check).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class GuardCheck:
    """One check: ``name`` (the counter's and the intervention's name) and ``what`` it does."""

    name: str
    what: str


GUARD_CHECKS: tuple[GuardCheck, ...] = (
    GuardCheck("soft_limit", "a position target clamped into the soft joint limits"),
    GuardCheck("hard_limit", "the estimate or a target past a hard limit (a safe stop)"),
    GuardCheck("velocity", "a speed clamped to what still stops before the soft limit"),
    GuardCheck("workspace", "a target whose end effector leaves the workspace box: held"),
    GuardCheck("self_collision", "a target in self-collision: held"),
    GuardCheck("effort", "a torque clamped to the derated effort limit"),
)

#: The checks' names in count-row order.
CHECKS: tuple[str, ...] = tuple(c.name for c in GUARD_CHECKS)


def row(name: str) -> int:
    """Row of check ``name`` in the guard's count matrix.

    Raises:
        KeyError: no such check (naming the known ones).
    """
    try:
        return CHECKS.index(name)
    except ValueError:
        raise KeyError(f"guard check '{name}': expected one of {CHECKS}") from None
