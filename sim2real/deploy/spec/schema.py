"""The JSON format of a PolicySpec: a pydantic model of the document, and its JSON Schema.

:meth:`sim2real.deploy.spec.policy_spec.PolicySpec.from_json` parses a spec file with
:class:`PolicySpecDocument`
(types, required fields, unknown fields refused), then expands the shorthands below and checks the
meaning with :meth:`sim2real.deploy.spec.policy_spec.PolicySpec.validate`. ``docs/policy_spec.schema.json``
is
:func:`json_schema` written out (``python -m sim2real.deploy.spec.schema docs/policy_spec.schema.json``);
a test checks the committed file equals the generated one.

Shorthands a hand-written spec may use (``PolicySpec.to_json`` always writes the explicit form):

- ``scale`` and ``offset`` of a block or of the action: a number (the same for every entry) or a
  list of ``size`` numbers; left out: ``scale`` 1, ``offset`` 0 (raw SI units).
- ``size`` left out: derived from the kind (3 for the vector blocks, the joint count for
  ``last_action`` and ``winding_temperature``, ``len(joints)`` for joint blocks, twice that for
  ``joint_position_sincos``; the action: one per joint).
- ``joints``: indices into ``joint_names`` or joint names; left out: every joint (for
  ``last_action`` and ``winding_temperature``: every joint the action drives).
- ``robot_hash`` left out or empty: the robot description hash is not checked (a policy trained
  elsewhere never saw our description; robot name, joint order and control rate still are).
- ``history`` left out: the graph reads one frame; given, only ``length`` is required.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from sim2real.deploy.spec.camera import IMAGES_DESCRIPTION, CameraError, image_blocks
from sim2real.deploy.spec.drive import DriveSpec
from sim2real.deploy.spec.height_scan import HeightScanPattern
from sim2real.deploy.spec.history import FILLS, LAYOUTS, ORDERS, ObservationHistory
from sim2real.deploy.spec.kinds import KINDS, kind_names
from sim2real.deploy.spec.policy_spec import (
    DEFAULT_CLIP,
    FORMAT_VERSION,
    UNCLIPPED,
    ActionSpec,
    ObservationBlock,
    PolicySpec,
    SpecError,
)
from sim2real.robots.schema import CONTROL_MODES

#: Where the committed schema lives, relative to the repository root.
SCHEMA_PATH = Path(__file__).resolve().parents[3] / "docs" / "policy_spec.schema.json"

_NUMBERS = "a number (every entry) or a list of one number per entry"


class _Doc(BaseModel):
    model_config = ConfigDict(extra="forbid")


class HeightScanDocument(_Doc):
    """A height_scan block's pattern (sim2real.deploy.spec.height_scan): a grid of points around
    the base where the sensor's height above the terrain is measured."""

    model_config = ConfigDict(title="HeightScan")

    x: list[float] = Field(description="Grid coordinates along the base's forward axis, m.")
    y: list[float] = Field(description="Grid coordinates along the base's left axis, m.")
    ordering: Literal["xy", "ij"] = Field(
        default="ij",
        description="xy: x varies fastest (Isaac Lab GridPatternCfg); ij: y fastest (legged_gym).",
    )
    alignment: Literal["yaw", "base", "world"] = Field(
        default="yaw",
        description="The grid turns with the base's yaw (legged_gym), its full attitude, or not.",
    )
    sensor_offset: list[float] = Field(
        default=[0.0, 0.0, 0.0],
        min_length=3,
        max_length=3,
        description="The point heights are measured from, relative to the base origin, m.",
    )


class ObservationBlockDocument(_Doc):
    """One observation block: ``obs = clip((raw - offset) / scale, -clip, clip)`` per entry."""

    model_config = ConfigDict(title="ObservationBlock")

    name: str = Field(
        description="Block kind: the raw quantity, in SI units and radians, base frame.",
        json_schema_extra={"enum": list(kind_names())},
    )
    size: int | None = Field(
        default=None, ge=0, description="Entries contributed; derived from the kind when left out."
    )
    scale: float | list[float] = Field(
        default=1.0,
        description=(
            f"Divisor of (raw - offset), {_NUMBERS}; finite and nonzero (negative flips the "
            "sign). A training library's "
            "multiplier s (legged_gym obs_scales) is scale = 1 / s."
        ),
    )
    offset: float | list[float] = Field(
        default=0.0, description=f"Subtracted from the raw value before scaling, {_NUMBERS}."
    )
    clip: float | None = Field(
        default=None,
        gt=0,
        description=(
            "Symmetric clip after scaling; default none (a clip the file does not state would "
            f"change what the policy sees; our own exports write {DEFAULT_CLIP:g})."
        ),
    )
    period: float | None = Field(
        default=None,
        gt=0,
        description=(
            "gait_phase: the gait clock's period, s (p = 2 pi t / period); motion_phase: the "
            "motion's length T, s (the block reads t / T); other blocks: none."
        ),
    )
    stand_below: float | None = Field(
        default=None,
        ge=0,
        description=(
            "gait_phase only: the clock stops while the velocity command's |(vx, vy)| (m/s) "
            "and |yaw rate| (rad/s) are both below it, every foot held at stand_phase; on the "
            "first tick above it the clock restarts at phase 0 (and an env's first tick reads "
            "one control period run, as holosoma_inference advances before it observes); "
            "default 0: the clock never stops."
        ),
    )
    stand_phase: float | None = Field(
        default=None,
        description="gait_phase only: the phase every foot is held at while standing, rad.",
    )
    joints: list[int | str] | None = Field(
        default=None,
        description=(
            "Joints read, in order (indices into joint_names, or names); default every joint. "
            "last_action and winding_temperature cover every joint the action drives (in any "
            "order)."
        ),
    )
    components: list[int] | None = Field(
        default=None,
        description=(
            "Vector blocks (base_linear_velocity, base_angular_velocity, projected_gravity, "
            "velocity_command, base_euler_angles) and gait_phase only: the entries of the raw "
            "vector read, in order. A vector: 0 x, 1 y, 2 z (a velocity command's vx, vy, yaw "
            "rate; Euler angles' roll, pitch, yaw); default all three. "
            "gait_phase: 0 sin p, 1 cos p, 2 sin(p + pi), 3 cos(p + pi) (a second foot half a "
            "period later), p = 2 pi t / period; default [0, 1]."
        ),
    )
    scan: HeightScanDocument | None = Field(
        default=None,
        description=(
            "height_scan only: where it measures the terrain; its size is the grid's points. The "
            "raw value is the sensor's height above the terrain, m (legged_gym's measured_heights "
            "is offset 0.5, scale 0.2, clip 5)."
        ),
    )


class ActionDocument(_Doc):
    """The action mapping: ``a' = clip(a, -clip, clip)``; ``target = offset + scale * a'``
    (reference 'absolute') or ``q + scale * a'`` (position mode, reference 'current')."""

    model_config = ConfigDict(title="Action")

    mode: str = Field(
        description="Control mode of the target: position (rad), velocity (rad/s), torque (N m).",
        json_schema_extra={"enum": list(CONTROL_MODES)},
    )
    size: int | None = Field(default=None, ge=1, description="Actions (= joints); default all.")
    scale: float | list[float] = Field(
        default=1.0, description=f"Units of the mode per unit action, {_NUMBERS}."
    )
    offset: float | list[float] = Field(
        default=0.0, description=f"Target for a zero action (e.g. a default pose), {_NUMBERS}."
    )
    clip: float | None = Field(
        default=None,
        gt=0,
        description=(
            "The action is clipped to [-clip, clip]; default none (a clip the file does not "
            "state would change what the policy does: a humanoid's targets past 1 fell)."
        ),
    )
    reference: Literal["absolute", "current"] = Field(
        default="absolute", description="'current' (position mode only): relative to q."
    )
    joints: list[int | str] | None = Field(
        default=None,
        description=(
            "The joint each output of the graph drives, in output order (indices into "
            "joint_names, or names; each at most once); default: output i drives joint i. scale "
            "and offset stay in joint_names order. Fewer outputs than joints: a joint no output "
            "drives has action 0 (its target is its offset)."
        ),
    )
    smoothing: Literal["none", "jerk_limited"] | None = Field(
        default=None,
        description=(
            "How the targets reached the drives in training, where the drives run a PD law on "
            "position targets: 'none', each target as the policy emitted it (legged_gym, Isaac "
            "Lab, mjlab: a target is a torque request); 'jerk_limited', through the runtime's "
            "Ruckig stage (the toolkit's own training). Default: the robot's ('none' for a "
            "PD-target robot; other robots' commands are always jerk-limited)."
        ),
    )


class DriveDocument(_Doc):
    """The PD gains and default pose the policy was trained with, one entry per joint in
    joint_names order; a list left out was not recorded (the robot's robot.toml holds)."""

    model_config = ConfigDict(title="Drive")

    kp: list[float] | None = Field(
        default=None, description="Position gains, N m/rad (> 0; 0 for a velocity drive)."
    )
    kd: list[float] | None = Field(default=None, description="Damping gains, N m s/rad (>= 0).")
    default_pose: list[float] | None = Field(
        default=None, description="The pose actions and joint observations are relative to, rad."
    )
    kinds: list[Literal["position", "velocity"]] | None = Field(
        default=None,
        description="Each joint's drive: 'position' (a PD target, rad) or 'velocity' (a speed "
        "target, rad/s, tau = kd (v_target - dq), kp 0: a wheel); left out: every joint position.",
    )


class HistoryDocument(_Doc):
    """The frame history the graph reads: the blocks' frames of the last ``length`` control ticks
    (sim2real/deploy/spec/history.py)."""

    model_config = ConfigDict(title="History")

    length: int = Field(ge=1, description="Ticks of history, the present one included.")
    order: Literal[ORDERS] = Field(  # type: ignore[valid-type]
        default="oldest_first",
        description="The ticks' order in the input (legged_gym, Isaac Lab: oldest_first).",
    )
    layout: Literal[LAYOUTS] = Field(  # type: ignore[valid-type]
        default="per_frame",
        description=(
            "per_frame: each tick's whole frame in turn (legged_gym frame_stack); per_term: each "
            "block's ticks in turn, then the next block's (Isaac Lab history_length)."
        ),
    )
    fill: Literal[FILLS] = Field(  # type: ignore[valid-type]
        default="zeros",
        description=(
            "What a tick before the policy's reset reads: zeros (humanoid-gym), or the first "
            "frame after it (first: Isaac Lab's CircularBuffer)."
        ),
    )
    lengths: list[int] | None = Field(
        default=None,
        description="per_term only: the ticks each block reads, one per block (1..length).",
    )


class PolicySpecDocument(_Doc):
    """A PolicySpec as stored in an ONNX file's ``policy_spec`` metadata or a ``--spec`` file."""

    model_config = ConfigDict(title="PolicySpec")

    format_version: Literal[FORMAT_VERSION] = Field(description="Version of this format.")  # type: ignore[valid-type]
    robot: str = Field(description="Robot name (sim2real/robots/<name>/robot.toml 'name').")
    joint_names: list[str] = Field(
        min_length=1, description="Joint order of observations and actions."
    )
    robot_hash: str = Field(
        default="",
        description="Robot.description_hash trained on; empty or left out: not checked.",
    )
    observation: list[ObservationBlockDocument] = Field(
        description="Ordered observation blocks; their sizes sum to the model's input size."
    )
    action: ActionDocument
    control_rate: float = Field(gt=0, description="Hz, the rate the policy was trained at.")
    baked: dict[str, bool] = Field(
        default_factory=dict,
        description="What the graph contains already (observation_normalizer, action_clip).",
    )
    parity: dict[str, Any] = Field(
        default_factory=dict, description="Parity figures of the export (written by export)."
    )
    constant_inputs: dict[str, float] = Field(
        default_factory=dict,
        description=(
            "Graph inputs besides the observation and recurrent state, fed this constant every "
            "tick (shape from the graph; a symbolic axis 0 is the batch)."
        ),
    )
    drive: DriveDocument | None = Field(
        default=None,
        description=(
            "PD gains and default pose of training (deploy-run runs the simulated plant with "
            "them; a backend that cannot set gains refuses differing ones)."
        ),
    )
    history: HistoryDocument | None = Field(
        default=None,
        description="The frame history the graph reads; left out: the present frame only.",
    )
    images: list[dict[str, Any]] = Field(default_factory=list, description=IMAGES_DESCRIPTION)


def parse_spec(text: str, source: str = "spec") -> PolicySpec:
    """:meth:`PolicySpec.from_json`: parse the JSON ``text``, check it against
    :class:`PolicySpecDocument`, expand the shorthands (:func:`to_spec`) and validate.

    Raises:
        SpecError: invalid JSON, unknown format version, missing, unknown or invalid field (the
            message starts with ``source`` and names the field).
    """
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SpecError(f"{source}: not valid JSON: {exc}") from exc
    if not isinstance(d, dict):
        raise SpecError(f"{source}: expected a JSON object")
    version = d.get("format_version")
    if version != FORMAT_VERSION:
        raise SpecError(
            f"{source}: format_version {version!r} is not supported; expected {FORMAT_VERSION}"
        )
    try:
        doc = PolicySpecDocument.model_validate(d)
    except ValidationError as exc:
        raise SpecError(f"{source}: {describe_error(exc)}") from None
    try:
        spec = to_spec(doc)
        spec.validate()
    except (SpecError, CameraError) as exc:  # CameraError: an images entry (to_spec)
        raise SpecError(f"{source}: {exc}") from None
    return spec


def to_spec(doc: PolicySpecDocument) -> PolicySpec:
    """The :class:`PolicySpec` of a parsed document, shorthands expanded (not yet validated).

    Raises:
        SpecError: a joint named in ``joints`` that is not in ``joint_names``. CameraError: an
            ``images`` entry :func:`~sim2real.deploy.spec.camera.image_blocks` refuses.
    """
    names = tuple(doc.joint_names)
    n = len(names)
    a = doc.action
    size = n if a.size is None else a.size
    action = ActionSpec(
        mode=a.mode,
        size=size,
        scale=_entries(a.scale, size),
        offset=_entries(a.offset, size),
        clip=UNCLIPPED if a.clip is None else float(a.clip),
        reference=a.reference,
        joints=tuple(_joint_index(j, names, "action.joints") for j in a.joints or ()),
        smoothing=a.smoothing or "",
    )
    blocks = [_block(i, b, names, action) for i, b in enumerate(doc.observation)]

    return PolicySpec(
        robot=doc.robot,
        joint_names=names,
        robot_hash=doc.robot_hash,
        observation_blocks=tuple(blocks),
        action=action,
        control_rate=float(doc.control_rate),
        baked=dict(doc.baked),
        parity=dict(doc.parity),
        format_version=doc.format_version,
        constant_inputs={k: float(v) for k, v in doc.constant_inputs.items()},
        drive=None
        if doc.drive is None
        else DriveSpec(
            kp=tuple(doc.drive.kp or ()),
            kd=tuple(doc.drive.kd or ()),
            default_pose=tuple(doc.drive.default_pose or ()),
            kinds=tuple(doc.drive.kinds or ()),
        ),
        history=None
        if doc.history is None
        else ObservationHistory(
            length=doc.history.length,
            order=doc.history.order,
            layout=doc.history.layout,
            fill=doc.history.fill,
            lengths=tuple(doc.history.lengths or ()),
        ),
        images=image_blocks(doc.images),
    )


def _block(i: int, b, names: tuple[str, ...], action: ActionSpec) -> ObservationBlock:
    """Observation entry ``i`` of a document as its block: its joints (by name; an every-joint
    block's default the joints the action drives) and its size (from its joints, its scan grid,
    its components or its kind).

    Raises:
        SpecError: a joint named that is not in ``joint_names``.
    """
    n = len(names)
    kind = KINDS.get(b.name)  # an unknown kind is refused by PolicySpec.validate
    per_joint = kind.per_joint if kind is not None else 0
    if b.joints is None:
        every = kind is not None and kind.every_joint
        # an every-joint block's default: the joints the action drives
        joints = (action.driven if every else tuple(range(n))) if per_joint else ()
    else:
        where = f"observation[{i}] ('{b.name}').joints"
        joints = tuple(_joint_index(j, names, where) for j in b.joints)
    size = b.size
    if size is None and per_joint:
        size = per_joint * len(joints)
    elif size is None and b.scan is not None:
        size = len(b.scan.x) * len(b.scan.y)
    elif size is None and b.components is not None:
        size = len(b.components)
    elif size is None:
        size = kind.size if kind is not None else 3
    return ObservationBlock(
        name=b.name,
        size=size,
        scale=_entries(b.scale, size),
        offset=_entries(b.offset, size),
        clip=UNCLIPPED if b.clip is None else float(b.clip),
        joints=joints,
        period=float(b.period or 0.0),
        components=tuple(int(c) for c in b.components or ()),
        stand_below=float(b.stand_below or 0.0),
        stand_phase=float(b.stand_phase or 0.0),
        scan=None if b.scan is None else HeightScanPattern.from_dict(b.scan.model_dump()),
    )


def _entries(value: float | list[float], size: int) -> tuple[float, ...]:
    """A JSON ``scale``/``offset``: one number for every entry, or the list as is (its length is
    checked by ``PolicySpec.validate``)."""
    if isinstance(value, (int, float)):
        return (float(value),) * size
    return tuple(float(x) for x in value)


def _joint_index(joint: int | str, names: tuple[str, ...], where: str) -> int:
    if isinstance(joint, str):
        if joint not in names:
            raise SpecError(f"{where}: joint '{joint}' is not in joint_names {list(names)}")
        return names.index(joint)
    return int(joint)


_UNION_MEMBER = re.compile(r"^(float|int|str|bool|none|(list|dict|tuple)\[.*\])$")


def describe_error(exc: ValidationError) -> str:
    """The first error of a pydantic ``ValidationError`` as ``field 'a.b[0].c': problem``."""
    err = exc.errors()[0]
    loc = ""
    for part in err["loc"]:
        if isinstance(part, str) and _UNION_MEMBER.match(part):
            continue  # pydantic names the member of a union it tried ('float', 'list[float]')
        loc += f"[{part}]" if isinstance(part, int) else (f".{part}" if loc else str(part))
    if err["type"] == "missing":
        return f"field '{loc}' is missing"
    if err["type"] == "extra_forbidden":
        return f"field '{loc}' is not a PolicySpec field (see docs/policy_spec.schema.json)"
    return f"field '{loc}': {err['msg']} (got {err.get('input')!r})"


def json_schema() -> dict[str, Any]:
    """The JSON Schema (draft 2020-12, as pydantic writes it) of a PolicySpec document."""
    schema = PolicySpecDocument.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    return schema


def schema_text() -> str:
    """:func:`json_schema` as the committed file holds it (sorted keys, 2-space indent)."""
    return json.dumps(json_schema(), indent=2, sort_keys=True) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Write the schema to the path given (default ``docs/policy_spec.schema.json``)."""
    argv = sys.argv[1:] if argv is None else argv
    path = Path(argv[0]) if argv else SCHEMA_PATH
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(schema_text())
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
