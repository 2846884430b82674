"""The plant's refusals: a MuJoCo state that diverged (:func:`check_divergence`, the warning
counters the compiled step screens, :data:`WARNING_SLICE`) and a command that is not finite."""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.robots.errors import Sim2RealError

#: The MuJoCo warnings that mean the state diverged.
DIVERGENCE_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADCTRL,
)
# The divergence warnings are consecutive in mjtWarning (BADQPOS..BADCTRL): the hot path checks
# them through one slice view of ``MjData.warning.number`` per env.
WARNING_SLICE = slice(
    min(int(w) for w in DIVERGENCE_WARNINGS), max(int(w) for w in DIVERGENCE_WARNINGS) + 1
)
assert WARNING_SLICE.stop - WARNING_SLICE.start == len(DIVERGENCE_WARNINGS)


class SimulationDivergedError(Sim2RealError, RuntimeError):
    """MuJoCo reported a divergence (non-finite or huge state); the session must fail loudly."""


class NonFiniteCommandError(Sim2RealError, ValueError):
    """A command with NaN or inf was written; it was rejected and never reached MuJoCo."""


def check_divergence(env: int, d: mujoco.MjData) -> None:
    """Raise :class:`SimulationDivergedError` if MuJoCo flagged ``d`` (env ``env``'s data) as
    diverged (the :data:`DIVERGENCE_WARNINGS` counters) or its ``qpos``/``qvel`` are not finite;
    else nothing."""
    bad = [w.name for w in DIVERGENCE_WARNINGS if d.warning[w].number > 0]
    if bad or not (np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()):
        raise SimulationDivergedError(
            f"env {env}: MuJoCo diverged at t={d.time:.4f} s "
            f"(warnings: {', '.join(bad) or 'none'}; "
            f"qpos={np.array2string(d.qpos, precision=3)})"
        )
