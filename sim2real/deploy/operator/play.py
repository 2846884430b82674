"""Play a remote script (:mod:`sim2real.deploy.backends.unitree.remote`) as another source would
send it, the buttons and sticks translated through two mappings: the same session driven from a
gamepad's recorded evdev stream, or by a second ROS 2 process publishing ``sensor_msgs/Joy``::

    python -m sim2real.deploy.operator.play SCRIPT --to xbox_evdev --out pad.jsonl
    python -m sim2real.deploy.operator.play SCRIPT --to xbox_joy [--topic /joy]

A held button becomes the buttons the target mapping gives the same action (``stand``, a policy,
...); a stick becomes the target's axis for the same command component, scaled so that the
command is the same (``value * scale_from / scale_to``, clipped to [-1, 1]). Times are the run's:
the script's time less its ``runtime_starts``. The ``/joy`` player waits for a subscriber (the
operator of a deploy-run), then ``--delay`` s for the runtime to start, then publishes the state
at 20 Hz (``joy_node``'s autorepeat rate) until the script's end plus 1 s.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from sim2real.deploy.backends.unitree.remote import RemoteScript, decode_remote
from sim2real.deploy.operator.mapping import COMPONENTS, Mapping, load_mapping, split_combo

#: The evdev axes' range and flat written into a stream's header (an Xbox pad's, xpad's).
EVDEV_ABSINFO = (-32768, 32767, 128)
#: Joy messages a second while the player publishes (joy_node's default autorepeat_rate).
JOY_RATE = 20.0


def translate(script: RemoteScript, src: Mapping, dst: Mapping) -> list[tuple[float, set, dict]]:
    """The script's states as ``(t, buttons, axes)`` in ``dst``'s names, ``t`` on the run's
    clock (module docstring).

    Raises:
        ValueError: ``src`` is not a ``unitree`` mapping, or an action held in the script has no
            button in ``dst``.
    """
    if src.source != "unitree":
        raise ValueError(f"a remote script plays through a unitree mapping, not '{src.source}'")
    keys = {f"action:{k}": v for k, v in src.actions.items()}
    keys.update({f"policy:{k}": v for k, v in src.policies.items()})
    targets = {f"action:{k}": v for k, v in dst.actions.items()}
    targets.update({f"policy:{k}": v for k, v in dst.policies.items()})
    out = []
    for at, raw in zip(script.times, script.states, strict=True):
        held, sticks = decode_remote(raw)
        buttons: set[str] = set()
        for key, combo in keys.items():
            if all(b in held for b in split_combo(combo)):
                if key not in targets:
                    raise ValueError(
                        f"'{key}' is held at {at} s; {dst.source} has no button for it"
                    )
                buttons.update(split_combo(targets[key]))
        axes = {}
        for c in COMPONENTS:
            a, b = getattr(src.command, c), getattr(dst.command, c)
            if b is not None:
                v = sticks.get(a.axis, 0.0) * a.scale / b.scale if a is not None else 0.0
                axes[b.axis] = float(np.clip(v, -1.0, 1.0))
        out.append((at - script.runtime_starts, buttons, axes))
    return out


def write_evdev(states, out: str | Path) -> Path:
    """Write ``states`` (:func:`translate`'s, evdev names) as a recorded stream (the JSON lines
    :class:`~sim2real.deploy.operator.sources.EvdevReplay` plays): an event where a button or an
    axis changes."""
    lo, hi, flat = EVDEV_ABSINFO
    axes_names = sorted({a for _, _, axes in states for a in axes})
    lines = [json.dumps({"absinfo": {a: [lo, hi, flat] for a in axes_names}})]
    held: set[str] = set()
    value: dict[str, int] = {}
    for t, buttons, axes in states:
        t = round(max(t, 0.0), 4)
        for b in sorted(held ^ buttons):
            lines.append(
                json.dumps({"t": t, "type": "EV_KEY", "code": b, "value": int(b in buttons)})
            )
        for a, v in sorted(axes.items()):
            raw = int(round(v * hi))
            if value.get(a) != raw:
                lines.append(json.dumps({"t": t, "type": "EV_ABS", "code": a, "value": raw}))
                value[a] = raw
        held = set(buttons)
    Path(out).write_text("\n".join(lines) + "\n")
    return Path(out)


def publish_joy(states, topic: str = "/joy", delay: float = 1.0, wait: float = 60.0) -> int:
    """Publish ``states`` (:func:`translate`'s, joy names) as ``sensor_msgs/Joy`` on ``topic``
    (module docstring); the messages published.

    Raises:
        TimeoutError: no subscriber within ``wait`` s.
    """
    from sensor_msgs.msg import Joy

    from sim2real.deploy.ros2.context import NodeThread

    n_buttons = 1 + max([int(b[6:]) for _, bs, _ in states for b in bs] or [10])
    n_axes = 1 + max([int(a[4:]) for _, _, ax in states for a in ax] or [7])
    sent = 0
    with NodeThread("sim2real_joy_player") as player:
        pub = player.node.create_publisher(Joy, topic, 10)
        end = time.monotonic() + wait
        while pub.get_subscription_count() == 0:
            if time.monotonic() > end:
                raise TimeoutError(f"no subscriber to {topic} within {wait} s")
            time.sleep(0.05)
        time.sleep(delay)
        t0, i = time.monotonic(), -1
        stop = states[-1][0] + 1.0
        while (t := time.monotonic() - t0) < stop:
            while i + 1 < len(states) and states[i + 1][0] <= t:
                i += 1
            msg = Joy()
            msg.header.stamp = player.node.get_clock().now().to_msg()
            buttons, axes = (states[i][1], states[i][2]) if i >= 0 else (set(), {})
            msg.buttons = [int(f"button{k}" in buttons) for k in range(n_buttons)]
            msg.axes = [float(axes.get(f"axis{k}", 0.0)) for k in range(n_axes)]
            pub.publish(msg)
            sent += 1
            time.sleep(1.0 / JOY_RATE)
    return sent


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim2real.deploy.operator.play", description=__doc__)
    p.add_argument("script", help="a remote script (TOML)")
    p.add_argument("--from", dest="src", default="unitree", help="its mapping (default unitree)")
    p.add_argument("--to", required=True, help="the target mapping (xbox_evdev, xbox_joy, a file)")
    p.add_argument("--out", default=None, help="evdev: the stream to write")
    p.add_argument("--topic", default="/joy", help="joy: the topic (default /joy)")
    p.add_argument("--delay", type=float, default=1.0, help="joy: s after a subscriber appears")
    args = p.parse_args(argv)
    try:
        dst = load_mapping(args.to)
        states = translate(RemoteScript(args.script), load_mapping(args.src), dst)
        if dst.source == "evdev":
            if not args.out:
                raise ValueError("--to an evdev mapping writes a stream: give --out FILE")
            print(write_evdev(states, args.out))
        elif dst.source == "joy":
            print(f"published {publish_joy(states, args.topic, args.delay)} Joy messages")
        else:
            raise ValueError(f"--to {args.to}: plays as evdev or joy, not {dst.source}")
    except (ValueError, TimeoutError) as exc:
        print(f"play: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
