"""The guard's checks: the one list that the guard's counters, the compiled kernel's count rows
and stages and the intervention monitor's names all come from.

A check (:class:`sim2real.deploy.safety.check.GuardCheck`) is what
:meth:`sim2real.deploy.safety.guard.SafetyGuard.filter` counts when it changes a target (an
intervention). Its row in ``SafetyGuard.count_matrix`` is its index in :data:`GUARD_CHECKS`, and
both the compiled guard (:func:`sim2real.deploy.safety.kernel.guard_filter`, through :data:`KERNELS`) and
the numpy reference (:mod:`sim2real.deploy.safety.reference`) run the checks in this order, so adding a
check is its class (numpy reference and compiled function) and one entry here; the guard's tests
compare the two paths check by check. The order of a stage matters where two checks act in the
same stage and mode (e.g. a clamp after another): soft_limit comes first (the intervention
monitor relies on it); pd_barrier, the clamp of PD targets (where soft_limit clamps none),
next.
"""

from __future__ import annotations

from sim2real.deploy.safety.check import GuardCheck
from sim2real.deploy.safety.limits import HardLimit, SoftLimit
from sim2real.deploy.safety.pd_barrier import PdBarrier
from sim2real.deploy.safety.predicted import Effort, SelfCollision, Workspace
from sim2real.deploy.safety.velocity import Velocity

GUARD_CHECKS: tuple[GuardCheck, ...] = (
    SoftLimit(),
    PdBarrier(),
    HardLimit(),
    Velocity(),
    Workspace(),
    SelfCollision(),
    Effort(),
)

#: The checks' names in count-row order.
CHECKS: tuple[str, ...] = tuple(c.name for c in GUARD_CHECKS)

#: The checks whose constants follow the estimate (:meth:`GuardCheck.prepare
#: <sim2real.deploy.safety.check.GuardCheck.prepare>`), which every filter runs first.
PREPARING = tuple(c for c in GUARD_CHECKS if type(c).prepare is not GuardCheck.prepare)

#: The checks' compiled functions in count-row order (the kernel unrolls over them).
KERNELS = tuple(c.kernel for c in GUARD_CHECKS)


def row(name: str) -> int:
    """Row of check ``name`` in the guard's count matrix.

    Raises:
        KeyError: no such check (naming the known ones).
    """
    try:
        return CHECKS.index(name)
    except ValueError:
        raise KeyError(f"guard check '{name}': expected one of {CHECKS}") from None
