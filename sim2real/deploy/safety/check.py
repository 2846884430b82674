"""One guard check: its name, what it does, its numpy reference and its compiled per-env function.

A check is a :class:`GuardCheck` subclass registered in :mod:`sim2real.deploy.safety.checks`; its count
row, its intervention name and its place in the compiled guard all follow from that list. Each
:meth:`SafetyGuard.filter <sim2real.deploy.safety.guard.SafetyGuard.filter>` runs the stages below in
order, every check in each stage in the list's order; a check acts in the stages and modes it
chooses and returns a code (:data:`FIRED`, :data:`NEEDS_PYTHON` bits):

- :data:`INSPECT`: read the raw target and the estimate (nothing written).
- :data:`CLAMP`: clamp the target in place.
- (the guard predicts the next state, ``pred``: :mod:`sim2real.deploy.safety.kernel`)
- :data:`PREDICTED`: read the predicted state; ask for :meth:`GuardCheck.resolve` (Pinocchio).
- (every check that asked resolves, in the list's order; an env held is skipped by the rest)
- :data:`FINAL`: clamp the target after the holds; counted on its own.

A check counts at most once per env over the first three stages (``FIRED`` in any of them);
``stops = True`` makes its firing a hard violation (the runtime's safe stop).
"""

from __future__ import annotations

import numpy as np

#: Stages of a filter, in their order.
INSPECT, CLAMP, PREDICTED, FINAL = 0, 1, 2, 3
#: Bits of a check's return code: counted; resolve in Python (Pinocchio) for this env.
FIRED, NEEDS_PYTHON = 1, 2
#: Control modes (``g.mode``).
POSITION, VELOCITY, TORQUE = 0, 1, 2
MODES = {"position": POSITION, "velocity": VELOCITY, "torque": TORQUE}
#: Rows of ``g.lim``, the robot's per-joint limits the checks share (rad, rad/s, rad/s^2, N m).
LOWER, UPPER, SOFT_LOWER, SOFT_UPPER, VEL, ACC, EFFORT = 0, 1, 2, 3, 4, 5, 6
LIM_ROWS = 7


class GuardCheck:
    """Base of a guard check; subclasses set ``name``, ``what`` and ``kernel`` and override
    :meth:`reference` (and :meth:`constants`, :meth:`resolve` where they need them).

    ``kernel`` is a ``numba.njit(cache=True, nogil=True, _nrt=False)`` function (no array
    created; :mod:`sim2real.deploy.kernels`) with the fixed signature
    ``kernel(stage, e, out, q, dq, commanded, has_commanded, g, own) -> int``: env ``e``'s
    share of one stage. ``out`` the target (envs, n), written in place by clamps; ``q``, ``dq``
    the estimate (envs, n); ``commanded`` velocity mode's integrated command (envs, n; ``q``
    when ``has_commanded`` is False); ``g`` the guard's arrays by name (its
    :class:`sim2real.deploy.safety.kernel.GuardArrays` or packed ``GUARD`` table);
    ``own`` this check's :meth:`constants` (rows, n). It must do the floating-point operations of
    :meth:`reference` in the same order (the tests compare them bit for bit).
    """

    name: str = ""
    what: str = ""
    stops: bool = False
    kernel = None

    def constants(self, guard) -> np.ndarray:
        """(rows, n) float64 per-joint constants of :attr:`kernel` (``own``); none by default."""
        return np.zeros((0, guard.robot.n_joints))

    def prepare(self, guard, state) -> None:
        """Before each filter, in Python: rewrite in place the rows of :meth:`constants` that
        follow the estimate (``state``, a :class:`~sim2real.deploy.core.state.RobotState`);
        nothing by default. Both the compiled guard and the reference read what it wrote."""

    def reference(self, stage: int, g, out, q, dq, commanded) -> tuple:
        """The numpy reference of :attr:`kernel` for every env at once: ``(fired, needs)``, each
        (envs,) bool or None (nothing). Arguments as :attr:`kernel`'s; ``commanded`` None when
        there is none; ``g`` the guard."""
        raise NotImplementedError

    def resolve(self, g, k: int, needs: np.ndarray, q, dq, out) -> None:
        """The Python (Pinocchio) part for the envs ``needs`` ((envs,) bool) asked for: count in
        ``g.count_matrix[k]``, change ``out`` (hold with ``g.reject``)."""
        raise NotImplementedError(f"guard check '{self.name}' asked for Python but has none")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"
