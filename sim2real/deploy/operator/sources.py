"""The operator's input sources, each an :class:`~sim2real.deploy.operator.frame.OperatorInput`:
the Unitree wireless remote (:class:`UnitreeRemote`, LowState's ``wireless_remote`` on
``rt/lowstate``; :class:`UnitreeController`, its own ``rt/wirelesscontroller``), ROS 2
``sensor_msgs/Joy`` (:class:`JoySource`), a Linux evdev gamepad (:class:`EvdevSource`, PyPI
``evdev``) or its recorded event stream (:class:`EvdevReplay`), the terminal keyboard
(:class:`KeyboardSource`) and a scripted remote (:class:`ScriptedRemote`). :func:`open_source`
opens one by its command-line name.

Times are the run's (``Runtime.time``, s): a frame's stamp is when the source last heard from
its device. A recorded evdev stream is JSON lines: a header ``{"absinfo": {"ABS_X": [min, max,
flat], ...}}``, then one event a line ``{"t": s, "type": "EV_KEY"|"EV_ABS", "code": "BTN_SOUTH",
"value": 1}`` (:func:`record_evdev` writes one from a device).
"""

from __future__ import annotations

import json
import os
import select
import threading
from pathlib import Path

import numpy as np

from sim2real.deploy.operator.frame import OperatorFrame, decode_unitree_remote


class _DdsRemote:
    """What the two DDS remotes share: the domain's link, the last frame heard and the samples
    heard (``samples``). A subclass opens its reader and reads the newest sample of its topic
    (:meth:`_newest`, None: nothing new) and decodes it into a frame (:meth:`_decode`).

    Raises:
        sim2real.deploy.backends.unitree.dds.DdsError: the domain cannot be joined.
    """

    source = "unitree"

    def __init__(self, domain_id: int, interface: str | None):
        from sim2real.deploy.backends.unitree.dds import DdsLink

        self._link = DdsLink(domain_id, interface)
        self._frame: OperatorFrame | None = None
        self.samples = 0

    def poll(self, now: float) -> OperatorFrame | None:
        newest = self._newest()
        if newest is not None:
            self.samples += 1
            self._frame = self._decode(newest, now)
        return self._frame

    def close(self) -> None:
        if self._link is not None:
            self._link.close()
            self._link = None


class UnitreeRemote(_DdsRemote):
    """The Unitree wireless remote, read from every ``rt/lowstate`` sample (a reader of its own
    beside the backend's, same domain and interface); a sample whose CRC fails is skipped
    (unless its ``crc`` is 0: a simulation bridge's).

    Args:
        family: ``unitree_go`` or ``unitree_hg``. domain_id, interface: as the backend's.

    Raises:
        sim2real.deploy.backends.unitree.dds.DdsError: the domain cannot be joined.
    """

    def __init__(self, family: str, domain_id: int, interface: str | None):
        from sim2real.deploy.backends.unitree.codec import MessageCodec
        from sim2real.deploy.backends.unitree.family import TOPIC_LOWSTATE
        from sim2real.deploy.backends.unitree.family import family as families

        fam = families(family)
        super().__init__(domain_id, interface)
        self._reader = self._link.reader(TOPIC_LOWSTATE, fam.low_state, 64)
        self._codec = MessageCodec(fam.low_state)

    def _newest(self) -> bytes | None:
        newest = None
        for data, _ in self._reader.take_raw(64):
            try:
                ok = self._codec.decode(data)
            except ValueError:
                continue
            if ok or int(self._codec.message["crc"]) == 0:
                newest = bytes(self._codec.message["wireless_remote"].tobytes())
        return newest

    def _decode(self, newest: bytes, now: float) -> OperatorFrame:
        return decode_unitree_remote(newest, now)


class UnitreeController(_DdsRemote):
    """The Unitree wireless remote on its own topic, ``rt/wirelesscontroller``
    (``WirelessController_``: the sticks and the button bits, no L2 analog value); heard from
    with every sample.

    Raises:
        sim2real.deploy.backends.unitree.dds.DdsError: the domain cannot be joined.
    """

    def __init__(self, domain_id: int, interface: str | None):
        from sim2real.deploy.backends.unitree.remote import TOPIC_CONTROLLER
        from sim2real.deploy.backends.unitree.unitree_go import WirelessController_

        super().__init__(domain_id, interface)
        self._reader = self._link.generic_reader(TOPIC_CONTROLLER, WirelessController_, 16)

    def _newest(self):
        newest = None
        for msg in self._reader.take(16):
            newest = msg
        return newest

    def _decode(self, newest, now: float) -> OperatorFrame:
        from sim2real.deploy.backends.unitree.remote import decode_controller

        buttons, axes = decode_controller(newest)
        return OperatorFrame(buttons, axes, now)


class ScriptedRemote:
    """A scripted Unitree remote (:class:`~sim2real.deploy.backends.unitree.remote.RemoteScript`)
    played on the run's clock, the script's time ``now + runtime_starts``: the emulator's session
    on any backend (``--operator-source unitree-script:FILE``); heard from at every poll.

    Raises:
        ValueError: a bad script (naming the file and step).
    """

    source = "unitree"

    def __init__(self, path: str | Path):
        from sim2real.deploy.backends.unitree.remote import RemoteScript

        self.script = RemoteScript(path)

    def poll(self, now: float) -> OperatorFrame | None:
        return decode_unitree_remote(self.script.at(now + self.script.runtime_starts), now)

    def close(self) -> None:
        """Nothing to release."""


class JoySource:
    """``sensor_msgs/Joy`` on ``topic`` (``joy_node``'s), through a node of its own
    (``sim2real_operator``); buttons ``button<i>``, axes ``axis<i>``.

    Raises:
        sim2real.deploy.ros2.context.Ros2UnavailableError: ROS 2 is not installed.
    """

    source = "joy"

    def __init__(self, topic: str = "joy", namespace: str = ""):
        from sensor_msgs.msg import Joy

        from sim2real.deploy.ros2.context import NodeThread

        self._thread = NodeThread("sim2real_operator", namespace)
        self._lock = threading.Lock()
        self._buttons: frozenset[str] = frozenset()
        self._axes: dict[str, float] = {}
        self._presses: set[str] = set()
        self._new = False
        self.received = 0
        self._thread.node.create_subscription(Joy, topic, self._on_joy, 10)
        self._frame: OperatorFrame | None = None
        self._thread.start()

    def _on_joy(self, msg) -> None:
        held = frozenset(f"button{i}" for i, b in enumerate(msg.buttons) if b)
        axes = {f"axis{i}": float(np.clip(a, -1.0, 1.0)) for i, a in enumerate(msg.axes)}
        with self._lock:
            self._presses |= held - self._buttons
            self._buttons, self._axes, self._new = held, axes, True
            self.received += 1

    def poll(self, now: float) -> OperatorFrame | None:
        with self._lock:
            if self._new:
                self._frame = OperatorFrame(
                    self._buttons, dict(self._axes), now, frozenset(self._presses)
                )
                self._presses.clear()
                self._new = False
            elif self._frame is not None and self._frame.presses:
                f = self._frame
                self._frame = OperatorFrame(f.buttons, f.axes, f.stamp)
        return self._frame

    def close(self) -> None:
        self._thread.close()


class _EvdevState:
    """Buttons held and axes in [-1, 1] from evdev events (``absinfo``: code -> (min, max,
    flat); an axis within ``flat`` of its centre reads 0)."""

    def __init__(self, absinfo: dict[str, tuple[float, float, float]]):
        self.absinfo = absinfo
        self.buttons: set[str] = set()
        self.presses: set[str] = set()
        self.axes: dict[str, float] = {}

    def apply(self, etype: str, code: str, value: float) -> None:
        if etype == "EV_KEY":
            if value:
                self.buttons.add(code)
                self.presses.add(code)
            else:
                self.buttons.discard(code)
        elif etype == "EV_ABS":
            lo, hi, flat = self.absinfo.get(code, (-1.0, 1.0, 0.0))
            centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
            v = 0.0 if abs(value - centre) <= flat else (value - centre) / half
            self.axes[code] = float(np.clip(v, -1.0, 1.0))

    def frame(self, stamp: float) -> OperatorFrame:
        f = OperatorFrame(frozenset(self.buttons), dict(self.axes), stamp, frozenset(self.presses))
        self.presses.clear()
        return f


class EvdevReplay:
    """A recorded evdev event stream (module docstring) played on the run's clock: the events
    up to ``now`` are applied at each poll; the device is heard from until the last event, then
    silent (a dead-man test).

    Raises:
        ValueError: an unreadable file or a malformed line (naming the file and line).
    """

    source = "evdev"

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            lines = self.path.read_text().splitlines()
        except OSError as exc:
            raise ValueError(
                f"evdev stream {self.path}: cannot read it ({exc.strerror or exc}); expected a "
                "recorded stream (JSON lines) or a device /dev/input/eventN"
            ) from None
        self.events: list[tuple[float, str, str, float]] = []
        absinfo = {}
        for i, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                d = json.loads(line)
                if "absinfo" in d:
                    absinfo = {k: tuple(float(x) for x in v) for k, v in d["absinfo"].items()}
                    continue
                self.events.append((float(d["t"]), d["type"], d["code"], float(d["value"])))
            except (ValueError, KeyError, TypeError) as exc:
                raise ValueError(
                    f"evdev stream {self.path}, line {i}: expected {{'t', 'type', 'code', "
                    f"'value'}} or an absinfo header: {exc}"
                ) from None
        self._state = _EvdevState(absinfo)
        self._next = 0
        self._heard = -np.inf

    def poll(self, now: float) -> OperatorFrame | None:
        ev = self.events
        while self._next < len(ev) and ev[self._next][0] <= now:
            _, etype, code, value = ev[self._next]
            self._state.apply(etype, code, value)
            self._next += 1
        if self._next == 0:
            return None
        self._heard = now if self._next < len(ev) else max(self._heard, ev[-1][0])
        return self._state.frame(self._heard)

    def close(self) -> None:
        """Nothing to release."""


class EvdevSource:
    """A Linux gamepad through python-evdev (``/dev/input/eventN``; read permission needed),
    read without blocking at each poll; heard from while the device is open.

    Raises:
        ValueError: python-evdev is not installed, or the device cannot be opened.
    """

    source = "evdev"

    def __init__(self, path: str):
        try:
            from evdev import InputDevice, ecodes
        except ImportError:
            raise ValueError("evdev gamepads need PyPI 'evdev' (pip install evdev)") from None
        try:
            self._dev = InputDevice(path)
        except OSError as exc:
            raise ValueError(f"evdev device {path}: {exc}") from None
        self._ecodes = ecodes
        absinfo = {}
        for code, info in self._dev.capabilities().get(ecodes.EV_ABS, []):
            absinfo[_name(ecodes.ABS, code)] = (info.min, info.max, info.flat)
        self._state = _EvdevState(absinfo)

    def poll(self, now: float) -> OperatorFrame | None:
        e = self._ecodes
        try:
            while True:
                event = self._dev.read_one()
                if event is None:
                    break
                if event.type == e.EV_KEY:
                    self._state.apply("EV_KEY", _name(e.keys, event.code), event.value)
                elif event.type == e.EV_ABS:
                    self._state.apply("EV_ABS", _name(e.ABS, event.code), event.value)
        except OSError:  # unplugged: no more frames, the dead-man acts
            return None
        return self._state.frame(now)

    def close(self) -> None:
        self._dev.close()


def _name(table: dict, code: int) -> str:
    """An evdev code's name (the first, where the kernel gives several: BTN_A is BTN_SOUTH)."""
    n = table.get(code, f"CODE_{code}")
    return n[0] if isinstance(n, (list, tuple)) else n


def record_evdev(device: str, out: str | Path, seconds: float) -> int:
    """Record ``seconds`` s of ``device``'s key and axis events into ``out`` (the JSON lines of
    :class:`EvdevReplay`); the number of events.

    Raises:
        ValueError: python-evdev is missing or the device cannot be opened.
    """
    import time

    src = EvdevSource(device)
    e, dev = src._ecodes, src._dev
    lines = [json.dumps({"absinfo": {k: list(v) for k, v in src._state.absinfo.items()}})]
    t0 = time.monotonic()
    while (t := time.monotonic() - t0) < seconds:
        select.select([dev.fd], [], [], 0.05)
        for event in iter(dev.read_one, None):
            if event.type in (e.EV_KEY, e.EV_ABS):
                kind = "EV_KEY" if event.type == e.EV_KEY else "EV_ABS"
                code = _name(e.keys if kind == "EV_KEY" else e.ABS, event.code)
                lines.append(
                    json.dumps({"t": round(t, 4), "type": kind, "code": code, "value": event.value})
                )
    src.close()
    Path(out).write_text("\n".join(lines) + "\n")
    return len(lines) - 1


#: The terminal's bytes for the keyboard's named keys.
_NAMED = {
    " ": "space",
    "\n": "enter",
    "\r": "enter",
    "\x1b": "esc",
    "\t": "tab",
    "\x7f": "backspace",
}


class KeyboardSource:
    """The terminal's keyboard (a key a press, no hold: a terminal reports no releases), read
    without blocking from ``fd`` (default stdin, put in cbreak mode while open when it is a
    terminal); heard from at each key.

    Raises:
        ValueError: ``fd`` is not readable.
    """

    source = "keyboard"

    def __init__(self, fd: int | None = None):
        import sys

        self.fd = sys.stdin.fileno() if fd is None else fd
        self._saved = None
        if os.isatty(self.fd):
            import termios
            import tty

            self._saved = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)
        self._heard: float | None = None

    def poll(self, now: float) -> OperatorFrame | None:
        if self._heard is None:
            self._heard = now  # the operator is at the keyboard when the run starts
        keys = set()
        while select.select([self.fd], [], [], 0)[0]:
            data = os.read(self.fd, 64)
            if not data:
                break
            for ch in data.decode(errors="replace"):
                keys.add(_NAMED.get(ch, ch.lower()))
        if keys:
            self._heard = now
        return OperatorFrame(frozenset(), {}, self._heard, frozenset(keys))

    def close(self) -> None:
        if self._saved is not None:
            import termios

            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            self._saved = None


#: The vocabulary (:data:`~sim2real.deploy.operator.frame.VOCABULARY`) of each source by its
#: command-line kind (the part of ``--operator-source`` before a ``:``).
KINDS = {
    "unitree": "unitree",
    "unitree-controller": "unitree",
    "unitree-script": "unitree",
    "joy": "joy",
    "evdev": "evdev",
    "keyboard": "keyboard",
}


def check_source(text: str) -> str:
    """Check the source named ``text`` (:func:`open_source`'s names) without opening a device:
    the name, and a file it plays (a recorded evdev stream, a scripted remote) read and parsed.
    Returns its vocabulary's name (``unitree``, ``joy``, ``evdev``, ``keyboard``).

    Raises:
        ValueError: an unknown name, a missing argument, or a file that does not read or parse
            (one line naming the option and the file).
    """
    kind, _, arg = text.partition(":")
    if kind not in KINDS:
        raise ValueError(
            f"--operator-source {text!r}: expected unitree, unitree-controller, "
            "unitree-script:FILE, joy[:TOPIC], evdev:PATH or keyboard"
        )
    if kind == "evdev" and not arg:
        raise ValueError("--operator-source evdev:PATH: name a device or a recorded stream")
    try:
        if kind == "evdev" and not arg.startswith("/dev/"):
            EvdevReplay(arg)
        elif kind == "unitree-script":
            ScriptedRemote(arg)
    except (ValueError, OSError) as exc:
        raise ValueError(f"--operator-source: {exc}") from None
    return KINDS[kind]


def open_source(text: str, *, backend_args=None, robot=None):
    """The source named ``text``: ``unitree`` (LowState's bytes), ``unitree-controller``
    (``rt/wirelesscontroller``), ``unitree-script:FILE`` (a scripted remote on the run's clock),
    ``joy[:TOPIC]``, ``evdev:/dev/input/eventN``, ``evdev:FILE`` (a recorded stream),
    ``keyboard``. ``backend_args``: deploy-run's parsed options (the Unitree backend's
    ``network_interface``, ``domain_id``, ``family``); ``robot``: its ``[unitree] family`` where
    ``family`` is not given.

    Raises:
        ValueError: an unknown name, or a source that cannot be opened.
    """
    kind, _, arg = text.partition(":")
    if kind == "unitree":
        a = backend_args
        cfg = getattr(getattr(robot, "config", None), "unitree", None)
        family = getattr(a, "family", None) or (cfg.family if cfg else "unitree_go")
        return UnitreeRemote(
            family, getattr(a, "domain_id", 0), getattr(a, "network_interface", None)
        )
    if kind == "unitree-controller":
        a = backend_args
        return UnitreeController(getattr(a, "domain_id", 0), getattr(a, "network_interface", None))
    if kind == "unitree-script":
        return ScriptedRemote(arg)
    if kind == "joy":
        return JoySource(arg or "joy")
    if kind == "evdev":
        if not arg:
            raise ValueError("--operator-source evdev:PATH: name a device or a recorded stream")
        return EvdevSource(arg) if arg.startswith("/dev/") else EvdevReplay(arg)
    if kind == "keyboard":
        return KeyboardSource()
    raise ValueError(
        f"--operator-source {text!r}: expected unitree, unitree-controller, unitree-script:FILE, "
        "joy[:TOPIC], "
        "evdev:PATH or keyboard"
    )
