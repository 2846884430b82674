"""Policies that carry their own contract: the metadata other training stacks write into the ONNX
file (or, for Isaac Lab, into the run folder beside it), read into a PolicySpec.

- :mod:`~sim2real.deploy.spec.foreign.registry`: the stacks' contract readers
  (:mod:`sim2real.stacks`), tried by rank, and :class:`OnnxFacts` (what a format looks at); used
  by :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy` and by ``policy-export --inspect``.
- :mod:`~sim2real.deploy.spec.foreign.contract`: :class:`ForeignContract`, a policy's contract in its
  stack's words (terms, multipliers, per-joint values by order or by regular expression).
- :mod:`~sim2real.deploy.spec.foreign.mapping`: a contract onto a robot: joints by name, terms onto
  observation blocks, scales, action scale and offset, PD gains and default pose.
- One module a format: :mod:`~sim2real.deploy.spec.foreign.mjlab`,
  :mod:`~sim2real.deploy.spec.foreign.holosoma`, :mod:`~sim2real.deploy.spec.foreign.isaaclab` (Isaac Lab and
  rsl_rl), :mod:`~sim2real.deploy.spec.foreign.unitree_deploy`, :mod:`~sim2real.deploy.spec.foreign.rl_sar`.

Our own ``policy_spec`` metadata, or a ``--spec`` file, always wins over a foreign contract.
"""

from sim2real.deploy.spec.foreign.contract import ForeignContract, ForeignFormatError, Term
from sim2real.deploy.spec.foreign.mapping import UNCLIPPED, to_spec
from sim2real.deploy.spec.foreign.registry import (
    OnnxFacts,
    detect_stack,
    known_formats,
    read_contract,
)

__all__ = [
    "UNCLIPPED",
    "ForeignContract",
    "ForeignFormatError",
    "OnnxFacts",
    "Term",
    "detect_stack",
    "known_formats",
    "read_contract",
    "to_spec",
]
