"""The PolicySpec of an ONNX policy: stored in the file, given, or built from a foreign contract.

``policy-export`` stores the spec as JSON in the model's ``policy_spec`` metadata
(:data:`METADATA_SPEC`). A spec given for a file that has one must agree with it (``baked`` and
``parity`` aside: :func:`spec_differences`); a file without one needs a given spec, or carries its
training stack's own contract (mjlab, holosoma, an Isaac Lab run folder:
:mod:`sim2real.deploy.spec.foreign`) from which the spec is built. Errors raise
:class:`~sim2real.deploy.spec.onnx_checks.PolicyLoadError` naming the file.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import onnx

from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError
from sim2real.robots import Robot

if TYPE_CHECKING:
    from sim2real.deploy.spec.foreign import ForeignContract

#: Metadata keys written by the exporter.
METADATA_SPEC = "policy_spec"


def spec_differences(a: PolicySpec, b: PolicySpec) -> list[str]:
    """Top-level fields in which two specs differ, ignoring ``baked`` and ``parity``."""
    da, db = json.loads(a.to_json()), json.loads(b.to_json())
    keys = sorted((set(da) | set(db)) - {"baked", "parity"})
    return [k for k in keys if da.get(k) != db.get(k)]


def read_spec(spec: PolicySpec | str | os.PathLike) -> PolicySpec:
    """A PolicySpec, or one read from a JSON file.

    Raises:
        SpecError: unreadable file or invalid spec (the message names the file).
    """
    if isinstance(spec, PolicySpec):
        return spec
    path = Path(spec)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SpecError(f"{path}: cannot read the spec file: {exc.strerror or exc}") from None
    return PolicySpec.from_json(text, source=str(path))


def resolve_spec(
    path: Path,
    spec: PolicySpec | str | os.PathLike | None,
    model: onnx.ModelProto,
    robot: Robot,
    metadata: Mapping[str, str],
) -> tuple[PolicySpec, ForeignContract | None]:
    """The spec in force for the ONNX file ``path``, and the foreign contract it was built from
    (None: the file's ``policy_spec`` metadata or the ``spec`` given).

    Raises:
        PolicyLoadError: an invalid stored or given spec, a given spec that contradicts the stored
            one, no spec at all, or a foreign contract that cannot be mapped onto ``robot``.
    """
    stored = None
    if METADATA_SPEC in metadata:
        try:
            stored = PolicySpec.from_json(
                metadata[METADATA_SPEC], source=f"{path}: metadata '{METADATA_SPEC}'"
            )
        except SpecError as exc:
            raise PolicyLoadError(str(exc)) from None
    given = None
    if spec is not None:
        try:
            given = read_spec(spec)
        except SpecError as exc:
            raise PolicyLoadError(f"{path}: {exc}") from None
    if stored is None and given is None:
        from sim2real.deploy.spec import foreign

        try:
            contract = foreign.read_contract(foreign.OnnxFacts.of(path, model))
            if contract is not None:
                return foreign.to_spec(contract, robot), contract
        except SpecError as exc:
            raise PolicyLoadError(str(exc)) from None
        from sim2real.deploy.spec.foreign import lerobot

        if lerobot.detect_onnx({p.key: p.value for p in model.metadata_props}):
            raise PolicyLoadError(
                f"{path}: a LeRobot export (metadata '{lerobot.METADATA_KEY}'): its chunks run "
                "through LeRobotChunkPolicy (sim2real.deploy.policy.lerobot_policy), as "
                f"`deploy-run --policy {path}` loads it"
            )
        raise PolicyLoadError(
            f"{path}: no '{METADATA_SPEC}' metadata (not written by policy-export) and no "
            f"training stack's own contract ({foreign.known_formats()}); pass the "
            "policy's spec (spec=PolicySpec or a spec JSON file)"
        )
    if stored is not None and given is not None:
        diff = spec_differences(stored, given)
        if diff:
            raise PolicyLoadError(
                f"{path}: the spec passed in differs from the one stored in the file in {diff}"
            )
    return (stored if stored is not None else given), None
