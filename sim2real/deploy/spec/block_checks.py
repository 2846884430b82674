"""The checks of a spec's observation blocks (:meth:`~sim2real.deploy.spec.policy_spec.PolicySpec.
validate`'s first part): each block's kind known and provided, its sizes, scales, clip, joints,
period, stand rule, components and height scan pattern consistent with the kind
(:mod:`sim2real.deploy.spec.kinds`)."""

from __future__ import annotations

import numpy as np

from sim2real.deploy.spec.kinds import KINDS, UNPROVIDED_KINDS, kind_names, vector_kind_names


def _problem(message: str) -> list[str]:
    return [message]


def observation_problems(blocks, n: int, driven: tuple[int, ...]) -> list[str]:
    """The first problem of ``blocks`` (:class:`~sim2real.deploy.spec.policy_spec.ObservationBlock`
    s, in order) as a one-entry list naming the block and field, or ``[]``.

    Args:
        blocks: The spec's observation blocks. n: Its joints. driven: The joints its action
            drives (an every-joint block must cover them once).
    """
    for i, b in enumerate(blocks):
        where = f"observation[{i}] ('{b.name}')"
        if b.name in UNPROVIDED_KINDS:
            here = UNPROVIDED_KINDS[b.name]
            return _problem(
                f"{where}: block '{b.name}' cannot be provided: "
                + (
                    f"this toolkit calls it '{here}'"
                    if here
                    else "no robot here measures it (the base height)"
                )
                + f"; blocks a robot provides: {', '.join(kind_names())}"
            )
        kind = KINDS.get(b.name)
        if kind is None:
            return _problem(
                f"{where}: block '{b.name}' is unknown: no robot provides it; expected one of "
                f"{kind_names()}"
            )
        if kind.periodic and not (np.isfinite(b.period) and b.period > 0):
            return _problem(f"{where}: period must be a positive number of s, got {b.period}")
        if (b.stand_below or b.stand_phase) and b.name != "gait_phase":
            return _problem(f"{where}: stand_below and stand_phase are for gait_phase blocks only")
        if not (np.isfinite(b.stand_below) and b.stand_below >= 0):
            return _problem(
                f"{where}: stand_below must be a command speed >= 0 (m/s, rad/s), got "
                f"{b.stand_below}"
            )
        if not np.isfinite(b.stand_phase):
            return _problem(
                f"{where}: stand_phase must be a finite phase, rad, got {b.stand_phase}"
            )
        if len(b.scale) != b.size or len(b.offset) != b.size:
            return _problem(f"{where}: scale and offset need {b.size} entries")
        if not all(np.isfinite(s) and s != 0 for s in b.scale):
            return _problem(f"{where}: scale must be finite and nonzero, got {b.scale}")
        if not b.clip > 0:
            return _problem(f"{where}: clip must be positive, got {b.clip}")
        if any(j < 0 or j >= n for j in b.joints):
            return _problem(f"{where}: joints {b.joints} out of range for {n} joints")
        if kind.every_joint and tuple(sorted(b.joints)) != driven:
            return _problem(
                f"{where}: joints must cover every joint the action drives once "
                f"({list(driven)}), got {list(b.joints)}"
            )
        if kind.scan != (b.scan is not None):
            return _problem(f"{where}: scan is for height_scan blocks, which need one")
        if kind.scan and b.scan.problems(where):
            return b.scan.problems(where)
        if kind.scan and sum(x.name == b.name for x in blocks) > 1:
            return _problem(f"{where}: one height_scan block per spec (the state holds one scan)")
        # per-foot kinds: the robot's feet (check_robot)
        expected = b.size if kind.per_foot else kind.block_size(len(b.joints))
        expected = b.scan.count if kind.scan else expected
        if b.components:
            if not kind.raw_entries:
                return _problem(f"{where}: components is for the blocks {vector_kind_names()} only")
            if any(c not in range(kind.raw_entries) for c in b.components):
                return _problem(
                    f"{where}: components {list(b.components)} must be in 0..{kind.raw_entries - 1}"
                )
            expected = len(b.components)
        if b.size != expected:
            return _problem(f"{where}: size {b.size}, expected {expected}")
    return []
