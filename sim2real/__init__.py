"""sim2real: the toolkit's public API, one uniquely named package a user's own folders cannot
shadow (a project with its own ``robots/`` folder beside it still imports this one).

>>> from sim2real import load_robot, PolicySpec
>>> arm = load_robot("arm3")
>>> PolicySpec.for_robot(arm).action.mode
'velocity'

Names load on first use (importing the package pulls in neither MuJoCo nor ONNX Runtime):

- robots: :func:`load_robot`, :class:`Robot`, :class:`RobotSpecError`;
- the policy: :class:`PolicySpec`, :class:`OnnxPolicy`, :func:`export_policy`,
  :func:`adversarial_model`;
- the runtime and its stages: :class:`Runtime`, :class:`SafetyGuard`, :class:`MotionEnvelope`,
  :class:`CommandSmoother`, :class:`JointStateEstimator`;
- backends: :class:`SimBackend` (MuJoCo plant), :class:`FeetechBackend`,
  :class:`DynamixelBackend` (serial-bus servos);
- monitors: :class:`ViolationMonitor`, :class:`InterventionMonitor`;
- the soak: :class:`SessionConfig`, :func:`run_campaign`.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
from pathlib import Path

#: The toolkit's own top-level packages, installed beside this one. Their names are generic: a
#: user's folder of robot descriptions called ``robots/`` in the working directory would be
#: imported in their place (a namespace package), so this package resolves them to its own
#: install location first.
_OWN = ("robots", "deploy", "eval", "policies")
_ROOT = Path(__file__).resolve().parent.parent


class _OwnPackages(importlib.abc.MetaPathFinder):
    """Finds the toolkit's own top-level packages (``_OWN``) at their install location."""

    def find_spec(self, name, path=None, target=None):
        if name not in _OWN:
            return None
        init = _ROOT / name / "__init__.py"
        if not init.is_file():
            return None
        return importlib.util.spec_from_file_location(
            name, init, submodule_search_locations=[str(init.parent)]
        )


def _claim_own_packages() -> None:
    """Put :class:`_OwnPackages` first on ``sys.meta_path``; refuse a same-named package that
    was imported from elsewhere already.

    Raises:
        ImportError: ``robots``, ``deploy``, ``eval`` or ``policies`` is already imported from
            another location (the message names it).
    """
    for name in _OWN:
        module = sys.modules.get(name)
        if module is None:
            continue
        locations = [Path(p).resolve() for p in getattr(module, "__path__", [])]
        if locations and _ROOT / name not in locations:
            raise ImportError(
                f"sim2real: the package '{name}' was already imported from "
                f"{', '.join(map(str, locations))}, not the toolkit's {_ROOT / name}: a folder "
                f"named '{name}' in the working directory or on sys.path shadows it; import "
                "sim2real first or rename that folder"
            )
    if not any(isinstance(f, _OwnPackages) for f in sys.meta_path):
        sys.meta_path.insert(0, _OwnPackages())


_claim_own_packages()

#: public name -> module that defines it
_SOURCES = {
    "load_robot": "robots",
    "Robot": "robots",
    "RobotSpecError": "robots",
    "PolicySpec": "deploy.spec.policy_spec",
    "OnnxPolicy": "deploy.policy.onnx_policy",
    "export_policy": "deploy.export.pipeline",
    "adversarial_model": "deploy.policy.adversarial",
    "Runtime": "deploy.runtime",
    "SafetyGuard": "deploy.safety.guard",
    "MotionEnvelope": "deploy.safety.envelope",
    "CommandSmoother": "deploy.smoothing",
    "JointStateEstimator": "deploy.estimation.joints",
    "SimBackend": "deploy.backends.sim.plant",
    "FeetechBackend": "deploy.backends.servo.feetech",
    "DynamixelBackend": "deploy.backends.servo.dynamixel",
    "ViolationMonitor": "deploy.monitors.violations",
    "InterventionMonitor": "deploy.monitors.interventions",
    "SessionConfig": "eval.soak.session",
    "run_campaign": "eval.soak.campaign",
}

from robots.lazy import lazy_names  # noqa: E402 (after the finder: the toolkit's robots)

__all__ = sorted(_SOURCES)


__getattr__ = lazy_names(__name__, _SOURCES, globals())


def __dir__() -> list[str]:
    return __all__
