"""sim2real: the toolkit's public API, one uniquely named package a user's own folders cannot
shadow (a project with its own ``sim2real/robots/`` folder beside it still imports this one).

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

from sim2real.numba_cache import install_when_numba_loads
from sim2real.robots.lazy import lazy_names

install_when_numba_loads()  # every kernel's cache keyed on its own sources (numba_cache)

#: public name -> module that defines it
_SOURCES = {
    "load_robot": "sim2real.robots",
    "Robot": "sim2real.robots",
    "RobotSpecError": "sim2real.robots",
    "PolicySpec": "sim2real.deploy.spec.policy_spec",
    "OnnxPolicy": "sim2real.deploy.policy.onnx_policy",
    "export_policy": "sim2real.deploy.export.pipeline",
    "adversarial_model": "sim2real.deploy.policy.adversarial",
    "Runtime": "sim2real.deploy.runtime",
    "SafetyGuard": "sim2real.deploy.safety.guard",
    "MotionEnvelope": "sim2real.deploy.safety.envelope",
    "CommandSmoother": "sim2real.deploy.smoothing",
    "JointStateEstimator": "sim2real.deploy.estimation.joints",
    "SimBackend": "sim2real.deploy.backends.sim.plant",
    "FeetechBackend": "sim2real.deploy.backends.servo.feetech",
    "DynamixelBackend": "sim2real.deploy.backends.servo.dynamixel",
    "ViolationMonitor": "sim2real.deploy.monitors.violations",
    "InterventionMonitor": "sim2real.deploy.monitors.interventions",
    "SessionConfig": "sim2real.eval.soak.session",
    "run_campaign": "sim2real.eval.soak.campaign",
}


__all__ = sorted(_SOURCES)


__getattr__ = lazy_names(__name__, _SOURCES, globals())


def __dir__() -> list[str]:
    return __all__
