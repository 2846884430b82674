"""The operator's mapping file (TOML, validated with pydantic): which button does what, how the
sticks become the velocity command, the dead-man rule, the hand-over's blend and who may move
the robot. :func:`load_mapping` reads one; ``shipped/`` holds the Unitree remote's, an
Xbox-layout gamepad's (evdev and ``sensor_msgs/Joy``) and the keyboard's (docs/operator.md has
their tables).

A button combination is written ``"L1+A"``: it fires once, when its last button goes down while
the others are held (a rising edge; holding it does nothing more). Names are the source's own
(:data:`sim2real.deploy.operator.frame.VOCABULARY`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from sim2real.deploy.operator.frame import SOURCES, expected_names, known_name

#: The folder of the shipped mappings (``deploy-run --operator unitree`` names one by its stem).
SHIPPED = Path(__file__).parent / "shipped"
#: Who may ask: the operator's input sources and the ROS 2 node's services.
REQUESTERS = (*SOURCES, "ros2")
#: The command's components: forward and lateral speed (m/s), yaw rate (rad/s), base frame.
COMPONENTS = ("vx", "vy", "yaw")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Axis(_Strict):
    """One component of the velocity command from one axis: ``scale * shaped(axis)``, where
    shaped is 0 within ``deadband`` of the centre and rescales the rest to [-1, 1]; the command
    moves towards it at ``rate_limit`` at most (units/s: m/s^2 or rad/s^2)."""

    axis: str
    scale: float = Field(description="m/s or rad/s at full deflection; its sign sets direction")
    deadband: float = Field(0.1, ge=0.0, lt=1.0)
    rate_limit: float = Field(2.0, gt=0.0)


class Command(_Strict):
    """How the sticks (or keys) become the command; ``keys``: keyboard steps, a key adding
    ``[component, step]`` to the command (clamped to ``limit``; a step 0 zeroes the command);
    ``heading_hold``: while walking with the yaw stick centred, the yaw rate holds the heading
    the robot had (:class:`sim2real.deploy.tasks.heading.HeadingHold`, legged_gym's heading
    command; gain 1/s, default its 0.5)."""

    vx: Axis | None = None
    vy: Axis | None = None
    yaw: Axis | None = None
    keys: dict[str, tuple[Literal["vx", "vy", "yaw"], float]] = {}
    limit: dict[Literal["vx", "vy", "yaw"], float] = {"vx": 1.0, "vy": 0.5, "yaw": 1.0}
    rate_limit: float = Field(2.0, gt=0.0, description="keys: units/s")
    heading_hold: float = Field(
        0.5, ge=0.0, description="1/s; a zero yaw rate holds the heading (0: off)"
    )


class Deadman(_Strict):
    """No frame from the source for ``timeout`` s: zero command; ``stand_after`` s more: STAND."""

    timeout: float = Field(0.5, gt=0.0)
    stand_after: float = Field(2.0, ge=0.0)


class Authority(_Strict):
    """The requesters that may leave PASSIVE or start a policy (``start``), end an operator's
    stop (``resume``), clear a latched fault of another cause (``reset``) and change the policy
    (``switch``); a stop (``damp``, the ROS 2 ``~/stop``) is open to all."""

    start: list[str] = Field(default_factory=list)
    resume: list[str] = Field(default_factory=list)
    reset: list[str] = Field(default_factory=list)
    switch: list[str] = Field(default_factory=list)

    @field_validator("start", "resume", "reset", "switch")
    @classmethod
    def _known(cls, names: list[str]) -> list[str]:
        for n in names:
            if n not in REQUESTERS:
                raise ValueError(f"unknown requester '{n}', expected one of {REQUESTERS}")
        return names


class Mapping(_Strict):
    """A mapping file (module docstring). ``actions``: ``stand``, ``damp``, ``lie_down``,
    ``next_policy`` (button combinations); ``policies``: a policy's name in the run -> its
    combination; ``blend_time``: s of a hand-over's blend; ``lie_time``: s of the blend to the
    lying policy's pose before damping; ``stand_time``: s of the ramp to home when standing up
    from PASSIVE (position mode; 0: at once; default 2 s, unitree_rl_gym deploy_real's move to
    the default pose); ``start``: the state after the runtime starts."""

    source: Literal["unitree", "joy", "evdev", "keyboard"]
    actions: dict[Literal["stand", "damp", "lie_down", "next_policy"], str]
    policies: dict[str, str] = {}
    command: Command = Command()
    deadman: Deadman = Deadman()
    authority: Authority | None = None
    blend_time: float = Field(0.5, ge=0.0)
    lie_time: float = Field(2.0, gt=0.0, description="s of the blend to the lying pose")
    stand_time: float = Field(2.0, ge=0.0, description="s of the stand-up's ramp from the floor")
    start: Literal["stand", "passive"] = "stand"

    @model_validator(mode="after")
    def _names(self):
        if "damp" not in self.actions:
            raise ValueError(
                "actions: 'damp' must have a button (an operator must be able to stop)"
            )
        combos = {**{f"actions.{k}": v for k, v in self.actions.items()}}
        combos.update({f"policies.{k}": v for k, v in self.policies.items()})
        for where, combo in combos.items():
            for name in split_combo(combo):
                if not known_name(self.source, name):
                    expected = expected_names(self.source, "button")
                    raise ValueError(f"{where}: '{name}' is not {expected}")
        for c in COMPONENTS:
            a = getattr(self.command, c)
            if a is not None and not known_name(self.source, a.axis):
                expected = expected_names(self.source, "axis")
                raise ValueError(f"command.{c}.axis: '{a.axis}' is not {expected}")
        for key in self.command.keys:
            if not known_name(self.source, key):
                expected = expected_names(self.source, "key")
                raise ValueError(f"command.keys: '{key}' is not {expected}")
        return self

    def allowed(self, right: str) -> list[str]:
        """The requesters holding ``right`` (``start``, ``resume``, ``reset``, ``switch``): the
        authority table's, or without one the mapping's own source alone."""
        if self.authority is None:
            return [self.source]
        return list(getattr(self.authority, right))


def split_combo(combo: str) -> tuple[str, ...]:
    """``"L1+A"`` -> ``("L1", "A")``; a lone ``"+"`` is the plus key."""
    if combo == "+":
        return ("+",)
    return tuple(p.strip() for p in combo.split("+") if p.strip())


def load_mapping(path: str | Path) -> Mapping:
    """Read and validate a mapping file; ``path`` may name a shipped mapping by its stem
    (``unitree``, ``xbox_evdev``, ``xbox_joy``, ``keyboard``).

    Raises:
        ValueError: an unreadable file, or fields that do not validate: one line naming the
            file, each field's path in it and what was expected (``; `` between fields).
    """
    p = Path(path)
    if not p.exists() and (SHIPPED / f"{path}.toml").exists():
        p = SHIPPED / f"{path}.toml"
    try:
        data = tomllib.loads(p.read_text())
    except OSError as exc:
        raise ValueError(f"operator mapping {p}: cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"operator mapping {p}: not TOML: {exc}") from None
    try:
        return Mapping.model_validate(data)
    except ValidationError as exc:
        fields = []
        for e in exc.errors():
            msg = e["msg"].removeprefix("Value error, ")
            if e["loc"]:
                where = ".".join(str(x) for x in e["loc"])
                fields.append(f"{where}: {msg} (got {e.get('input')!r})")
            else:  # a check across fields names its own
                fields.append(msg)
        raise ValueError(f"operator mapping {p}: " + "; ".join(fields)) from None
