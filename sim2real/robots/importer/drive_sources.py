"""Where a legged robot's kp, kd and home pose come from, joint by joint (:func:`choose`).

Four sources, the first that gives a joint's value wins:

1. the flags (``--kp``, ``--kd``, ``--home``, shell patterns);
2. a policy's contract (``--drive-from POLICY``: what its stack recorded);
3. the robot file itself (an MJCF's ``<position>`` actuators and ``<keyframe>``,
   :mod:`sim2real.robots.importer.mjcf_drive`);
4. the importer's rule (:func:`sim2real.robots.importer.model.derive_motion_limits`).

:func:`source_lines` says which source gave which joints, one line per quantity, for the import's
printout; robot.toml repeats the source beside each joint's gains.
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: The quantities chosen, in the order printed.
QUANTITIES = ("kp", "kd", "home")
#: The source texts of the flags' values: each quantity names its own flag (a kp from ``--kp``
#: never credits ``--kd``, nor a home pose the ``--note`` lines).
FLAG_SOURCES = {"kp": "--kp", "kd": "--kd", "home": "--home"}
#: The source of a value no flag, policy or file gives.
RULE = "the importer's rule (see above)"


@dataclass
class DriveChoice:
    """The chosen values and their sources.

    Attributes:
        values: quantity -> joint -> value (N m/rad, N m s/rad, rad), only the joints a flag,
            policy or file gives (the importer's rule fills the rest).
        sources: quantity -> joint -> the source's text, for every joint.
    """

    values: dict[str, dict[str, float]] = field(default_factory=dict)
    sources: dict[str, dict[str, str]] = field(default_factory=dict)

    def gains_note(self, joint: str) -> tuple[str, str]:
        """robot.toml's comments on ``joint``'s kp and kd: where each came from."""
        return self.sources["kp"][joint], self.sources["kd"][joint]


def choose(
    joints: list[str],
    flags: dict[str, dict[str, float]],
    policy: tuple[dict[str, dict[str, float]], str] | None = None,
    drive=None,
) -> DriveChoice:
    """Each joint's kp, kd and home from the first source that gives it (module docstring).

    Args:
        joints: The robot's joints. flags: quantity -> joint -> value of the flags.
        policy: (quantity -> joint -> value, the contract's description) of ``--drive-from``.
        drive: The robot file's :class:`sim2real.robots.importer.mjcf_drive.SourceDrive`
            (None: a URDF).
    """
    layers: list[tuple[dict[str, dict[str, float]], dict[str, str]]] = []
    layers.append((flags, FLAG_SOURCES))
    if policy is not None:
        values, source = policy
        layers.append((values, {q: f"the policy's (--drive-from: {source})" for q in QUANTITIES}))
    if drive is not None:
        values = {
            "kp": {j: v for j, (v, _) in drive.kp.items()},
            "kd": {j: v for j, (v, _) in drive.kd.items()},
            "home": dict(drive.home),
        }
        texts = {"kp": {j: s for j, (_, s) in drive.kp.items()},
                 "kd": {j: s for j, (_, s) in drive.kd.items()}}  # fmt: skip
        layers.append((values, {"home": drive.home_source, **texts}))
    choice = DriveChoice({q: {} for q in QUANTITIES}, {q: {} for q in QUANTITIES})
    for q in QUANTITIES:
        for j in joints:
            for values, source in layers:
                if j in values.get(q, {}):
                    choice.values[q][j] = float(values[q][j])
                    text = source[q]
                    choice.sources[q][j] = text if isinstance(text, str) else text[j]
                    break
            else:
                choice.sources[q][j] = RULE
    return choice


def source_lines(choice: DriveChoice, joints: list[str]) -> list[str]:
    """One printed line per quantity: ``"kp: <source> (every joint)"``, or each source with the
    joints it gave, in joint order."""
    lines = []
    for q in QUANTITIES:
        by_source: dict[str, list[str]] = {}
        for j in joints:
            by_source.setdefault(_family(choice.sources[q][j]), []).append(j)
        if len(by_source) == 1:
            lines.append(f"{q}: {next(iter(by_source))} (every joint)")
            continue
        parts = [f"{src} for {names}" for src, names in by_source.items()]
        lines.append(f"{q}: " + "; ".join(parts))
    return lines


def _family(source: str) -> str:
    """A source's text without the element's own name (one MJCF actuator per joint would make
    one group per joint): ``"MJCF <position> kp"``."""
    if source.startswith("MJCF <position name="):
        return "MJCF <position> " + source.rsplit("> ", 1)[1]
    return source
