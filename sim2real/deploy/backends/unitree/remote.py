"""The Unitree wireless remote's 40 bytes (LowState's ``wireless_remote``; unitree_sdk2's
``xRockerBtnDataStruct``) and a scripted remote for the emulator (:class:`RemoteScript`).

The layout, as unitree_rl_gym's ``deploy_real/common/remote_controller.py`` reads it: bytes 0-1 a
header, 2-3 a little-endian uint16 of 16 button bits (bit 0 R1, 1 L1, 2 start, 3 select, 4 R2,
5 L2, 6 F1, 7 F2, 8 A, 9 B, 10 X, 11 Y, 12 up, 13 right, 14 down, 15 left), then float32 ``lx``
at 4, ``rx`` at 8, ``ry`` at 12, the L2 trigger at 16, ``ly`` at 20 (sticks in [-1, 1], up and
right positive), the rest idle.

A remote script (TOML) is a list of states, each held from its time until the next (and
optionally ``runtime_starts``, s: where a run's clock starts on the script's, for playing it
without the emulator: ``deploy-run --operator-source unitree-script:FILE``)::

    [[step]]
    at = 2.0             # s after the first LowCmd (the emulator's fault clock)
    buttons = ["start"]  # held; a button not named is up
    ly = 0.0             # sticks: lx, ly, rx, ry, L2 (0 when not given)
"""

from __future__ import annotations

import bisect
import struct
from pathlib import Path

import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

#: The button bits, bit i named ``BUTTONS[i]`` (unitree_rl_gym's ``KeyMap``).
BUTTONS = (
    "R1", "L1", "start", "select", "R2", "L2", "F1", "F2",
    "A", "B", "X", "Y", "up", "right", "down", "left",
)  # fmt: skip
#: The analog values and their byte offsets (float32, little-endian).
AXES = {"lx": 4, "rx": 8, "ry": 12, "L2": 16, "ly": 20}
#: Size of the ``wireless_remote`` field, bytes (unitree_go / unitree_hg LowState IDL).
REMOTE_BYTES = 40
#: The remote's own topic (``unitree_go`` ``WirelessController_``: lx, ly, rx, ry, keys).
TOPIC_CONTROLLER = "rt/wirelesscontroller"


def controller_message(data):
    """The ``WirelessController_`` sample of the remote's 40 bytes ``data`` (the same button bits
    and sticks; ``L2``'s analog value has no field there)."""
    from sim2real.deploy.backends.unitree.unitree_go import WirelessController_

    buttons, axes = decode_remote(data)
    keys = sum(1 << BUTTONS.index(b) for b in buttons)
    return WirelessController_(
        lx=axes["lx"], ly=axes["ly"], rx=axes["rx"], ry=axes["ry"], keys=keys
    )


def decode_controller(msg) -> tuple[frozenset[str], dict[str, float]]:
    """``(buttons held, {axis: value})`` of a ``WirelessController_`` sample."""
    keys = int(msg.keys)
    buttons = frozenset(name for i, name in enumerate(BUTTONS) if keys >> i & 1)
    axes = {}
    for name in ("lx", "ly", "rx", "ry"):
        v = float(getattr(msg, name))
        axes[name] = float(np.clip(v, -1.0, 1.0)) if np.isfinite(v) else 0.0
    return buttons, axes


def encode_remote(buttons=(), **axes: float) -> bytes:
    """The 40 bytes for ``buttons`` held and the ``axes`` given (the rest 0).

    Raises:
        ValueError: an unknown button or axis name.
    """
    raw = bytearray(REMOTE_BYTES)
    bits = 0
    for b in buttons:
        if b not in BUTTONS:
            raise ValueError(f"Unitree remote: unknown button '{b}'; expected one of {BUTTONS}")
        bits |= 1 << BUTTONS.index(b)
    struct.pack_into("<H", raw, 2, bits)
    for name, value in axes.items():
        if name not in AXES:
            raise ValueError(
                f"Unitree remote: unknown axis '{name}'; expected one of {tuple(AXES)}"
            )
        struct.pack_into("<f", raw, AXES[name], float(value))
    return bytes(raw)


def decode_remote(data) -> tuple[frozenset[str], dict[str, float]]:
    """``(buttons held, {axis: value})`` of the 40 bytes ``data`` (bytes or a uint8 array);
    sticks clipped to [-1, 1], a non-finite value read as 0.

    Raises:
        ValueError: not 40 bytes.
    """
    raw = (
        bytes(data)
        if isinstance(data, (bytes, bytearray))
        else np.asarray(data, np.uint8).tobytes()
    )
    if len(raw) != REMOTE_BYTES:
        raise ValueError(f"wireless_remote: expected {REMOTE_BYTES} bytes, got {len(raw)}")
    (keys,) = struct.unpack_from("<H", raw, 2)
    buttons = frozenset(name for i, name in enumerate(BUTTONS) if keys >> i & 1)
    axes = {}
    for name, offset in AXES.items():
        (v,) = struct.unpack_from("<f", raw, offset)
        axes[name] = float(np.clip(v, -1.0, 1.0)) if np.isfinite(v) else 0.0
    return buttons, axes


class RemoteScript:
    """A scripted remote (module docstring): :meth:`at` gives the bytes at a time.

    Args:
        path: The TOML script.

    Raises:
        ValueError: an unreadable file, a step without ``at``, times not increasing, an unknown
            button or axis (each naming the file and the step).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            data = tomllib.loads(self.path.read_text())
            steps = data.get("step", [])
            #: s, the run's time 0 on the script's clock (``runtime_starts``; default 0)
            self.runtime_starts = float(data.get("runtime_starts", 0.0))
        except (OSError, tomllib.TOMLDecodeError) as exc:
            raise ValueError(f"remote script {self.path}: {exc}") from None
        self.times: list[float] = []
        self.states: list[bytes] = []
        for i, step in enumerate(steps):
            step = dict(step)
            where = f"remote script {self.path}: step {i + 1}"
            at = step.pop("at", None)
            if not isinstance(at, (int, float)) or (self.times and at < self.times[-1]):
                raise ValueError(f"{where}: 'at' must be a time in s, not before the last step's")
            try:
                self.states.append(encode_remote(step.pop("buttons", ()), **step))
            except (ValueError, TypeError) as exc:
                raise ValueError(f"{where}: {exc}") from None
            self.times.append(float(at))

    def at(self, t: float) -> bytes:
        """The remote's bytes at ``t`` s (nothing held before the first step)."""
        i = bisect.bisect_right(self.times, t) - 1
        return self.states[i] if i >= 0 else bytes(REMOTE_BYTES)
