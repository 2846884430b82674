"""deploy-run's several policies and its operator: ``--policy [NAME=]FILE`` (repeated; a file
without a name is named by its stem), ``--operator MAPPING`` and ``--operator-source SOURCE``
(:mod:`sim2real.deploy.operator`), and the policy a clip run hands over to at the clip's end
(``--after-clip``: :func:`after_clip_policy`, :mod:`sim2real.deploy.rig.after_clip`).

Every policy of a run must fit the robot (its contract, :meth:`PolicySpec.check_robot`) and drive
it the same way: the same control mode, and where a policy records its drive (PD gains, default
pose), the same as the first's, since the robot's drives are set once for the run.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from sim2real.deploy.rig.after_clip import DEFAULT_POSE, DEFAULT_POSE_RAMP_S


def add_operator_options(p: argparse.ArgumentParser) -> None:
    """Add ``--operator``, ``--operator-source``, ``--lie-policy`` and ``--stand-policy``."""
    g = p.add_argument_group("operator (docs/operator.md)")
    g.add_argument(
        "--operator",
        default=None,
        metavar="MAPPING",
        help="drive the run from an operator's input: a mapping file (TOML) or a shipped one "
        "(unitree, xbox_evdev, xbox_joy, keyboard)",
    )
    g.add_argument(
        "--operator-source",
        default=None,
        metavar="SOURCE",
        help="unitree (the wireless remote in LowState), joy[:TOPIC] (sensor_msgs/Joy), "
        "evdev:/dev/input/eventN or evdev:FILE.jsonl (a recorded stream), keyboard; default: "
        "the mapping's source",
    )
    g.add_argument(
        "--lie-policy",
        default="lie",
        metavar="NAME",
        help="the policy (by its --policy NAME) whose pose the robot lies down in before its "
        "drives damp (default %(default)s; absent: lie_down damps at once)",
    )
    g.add_argument(
        "--stand-policy",
        default="stand",
        metavar="NAME",
        help="the policy (by its --policy NAME) that holds the robot standing (default "
        "%(default)s; absent: STAND runs the walking policy at a zero command)",
    )


def parse_policies(values: list[str]) -> dict[str, str]:
    """``--policy`` values -> {name: file}, in order.

    Raises:
        ValueError: an empty name or file, a name given twice.
    """
    out: dict[str, str] = {}
    for v in values:
        name, sep, path = v.partition("=")
        if not sep:
            name, path = Path(v).stem, v
        if not name or not path:
            raise ValueError(f"--policy {v!r}: expected FILE or NAME=FILE")
        if name in out:
            raise ValueError(f"--policy {v!r}: the name '{name}' is given twice")
        out[name] = path
    return out


def load_policies(
    files: dict[str, str], robot, spec=None, inference: str = "sync", seed: int = 0
) -> dict:
    """{name: OnnxPolicy} of ``files`` for ``robot`` (``spec``: --spec, for every file;
    ``inference``: --inference, a LeRobot export's network call, ``"sync"`` or ``"async"``;
    ``seed``: --seed, a LeRobot Diffusion Policy's noise generator).

    Raises:
        ValueError: a policy that does not load or fit the robot, or that drives it another way
            than the first (control mode, kp, kd or default pose; naming both files).
    """
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.drive import drive_robot

    policies, first = {}, None
    for name, path in files.items():
        policy = _lerobot_policy(path, robot, spec, inference, seed) or OnnxPolicy(
            path, robot, spec=spec
        )
        driven, _ = drive_robot(robot, policy.spec)
        drive = (
            policy.spec.action.mode,
            np.array([j.kp for j in driven.config.joints]),
            np.array([j.kd for j in driven.config.joints]),
            np.asarray(driven.home),
        )
        if first is None:
            first = (path, drive)
        else:
            for label, a, b in zip(
                ("control mode", "kp", "kd", "home pose"), first[1], drive, strict=True
            ):
                if not np.array_equal(np.asarray(a), np.asarray(b)):
                    raise ValueError(
                        f"--policy {name}={path}: its {label} differs from {first[0]}'s; the "
                        f"policies of one run drive the robot alike ({b} vs {a})"
                    )
        policies[name] = policy
    return policies


def _lerobot_policy(path: str, robot, spec, inference: str = "sync", seed: int = 0):
    """A LeRobot export (its ``lerobot_contract`` metadata) as the runtime's chunked policy
    (:class:`~sim2real.deploy.policy.lerobot_policy.LeRobotChunkPolicy`), or None for any other
    file (the :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy` reads it).

    Raises:
        ValueError: ``--spec`` given for a LeRobot export (its contract is its spec), or the
            export refused for the robot (LeRobotFormatError, one line naming the file).
    """
    import onnx

    from sim2real.deploy.spec.foreign import lerobot

    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception:  # noqa: BLE001 - not a readable ONNX file: OnnxPolicy says why in one line
        return None
    if not lerobot.detect_onnx({p.key: p.value for p in model.metadata_props}):
        return None
    if spec is not None:
        raise ValueError(
            f"{path}: a LeRobot export carries its own contract ('{lerobot.METADATA_KEY}'); "
            "expected no --spec"
        )
    if lerobot.read_onnx(path).policy_type == "diffusion":
        from sim2real.deploy.policy.lerobot_diffusion_policy import DiffusionChunkPolicy

        return DiffusionChunkPolicy(path, robot, seed=seed, inference=inference)
    from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy

    return LeRobotChunkPolicy(path, robot, inference=inference)


def operator_mapping(args):
    """The :class:`~sim2real.deploy.operator.mapping.Mapping` of ``--operator`` (None without
    it), its ``--operator-source`` checked but not opened
    (:func:`~sim2real.deploy.operator.sources.check_source`): read before anything opens.

    Raises:
        ValueError: ``--operator-source`` without ``--operator``; ``--envs`` other than 1; no
            walking policy (``args.policies`` all ``--stand-policy`` or ``--lie-policy``); a bad
            mapping; a bad source or one whose file does not read; a mapping for another source.
    """
    if not args.operator:
        if args.operator_source:
            raise ValueError("--operator-source needs --operator MAPPING")
        return None
    from sim2real.deploy.operator.mapping import load_mapping
    from sim2real.deploy.operator.sources import check_source

    if args.envs != 1:  # the machine's own checks, made before anything opens
        raise ValueError(f"--operator drives one robot: --envs must be 1, got {args.envs}")
    if all(n in (args.stand_policy, args.lie_policy) for n in args.policies):
        raise ValueError(
            f"--operator: the run has no walking policy besides '{args.stand_policy}', "
            f"'{args.lie_policy}' (--policy NAME=FILE)"
        )
    mapping = load_mapping(args.operator)
    text = args.operator_source or mapping.source
    kind = check_source(text)
    if kind != mapping.source:
        raise ValueError(
            f"--operator {args.operator}: a mapping for '{mapping.source}', the source "
            f"'{text}' gives {kind} names"
        )
    return mapping


def open_operator_source(args, mapping, robot):
    """Open ``mapping``'s source (``--operator-source``, default the mapping's own); None
    without a mapping.

    Raises:
        ValueError: a source that does not open (a device, ROS 2, the DDS domain).
    """
    if mapping is None:
        return None
    from sim2real.deploy.operator.sources import open_source

    return open_source(args.operator_source or mapping.source, backend_args=args, robot=robot)


def operator_hook(args, rig, policies: dict, mapping, source):
    """The :class:`~sim2real.deploy.operator.hook.OperatorHook` of ``--operator`` on the opened
    ``source`` (:func:`operator_mapping`, :func:`open_operator_source`); None without them."""
    if mapping is None or source is None:
        return None
    from sim2real.deploy.operator.hook import OperatorHook
    from sim2real.deploy.operator.machine import OperatorMachine

    machine = OperatorMachine(
        rig.runtime, policies, mapping, [source], args.stand_policy, args.lie_policy
    )
    for name in machine.unknown_policies:
        print(
            f"deploy-run: note: the mapping names policy '{name}', not in this run (its "
            f"button does nothing); the run's: {list(policies)}",
            file=sys.stderr,
        )
    return OperatorHook(rig, machine, args.operator)


def after_clip_policy(args, policies: dict, first) -> tuple[str, object] | None:
    """The policy a clip run hands the robot to at the clip's end (``--after-clip NAME``;
    without it, the run's second ``--policy`` when there is no ``--operator``), as ``(name,
    policy)``; None: the clip's end is a hold (``--motion-playback``), judged.

    Raises:
        ValueError: a name no ``--policy`` gives, the first policy named, ``--operator`` or
            ``--motion-playback`` given too, ``--envs`` other than 1, a negative
            ``--after-clip-blend``.
    """
    name = args.after_clip
    if name == DEFAULT_POSE:
        return _default_pose(args, policies)
    if name is None:
        from sim2real.deploy.tasks.motion.source import reads_motion

        if getattr(args, "operator", None) or len(policies) < 2 or not reads_motion(first.spec):
            return None
        name = list(policies)[1]
    if getattr(args, "operator", None):
        raise ValueError(
            f"--after-clip {name} and --operator: the operator's buttons switch the policies; "
            "give one of them"
        )
    if name not in policies or policies[name] is first:
        raise ValueError(
            f"--after-clip {name}: expected the NAME of a --policy NAME=FILE after the first "
            f"(the run's: {list(policies)})"
        )
    if args.envs != 1:
        raise ValueError(
            f"--after-clip {name}: a hand-over drives one robot: --envs must be 1, got {args.envs}"
        )
    if args.motion_playback is not None:
        raise ValueError(
            f"--motion-playback {args.motion_playback} and a hand-over to '{name}' at the "
            "clip's end: give one of them"
        )
    if args.after_clip_blend is None:
        args.after_clip_blend = 0.0  # rl_sar's: at once
    if not args.after_clip_blend >= 0.0:
        raise ValueError(f"--after-clip-blend {args.after_clip_blend}: expected s >= 0")
    return name, policies[name]


def _default_pose(args, policies: dict) -> tuple[str, None]:
    """``--after-clip default-pose`` (:data:`~sim2real.deploy.rig.after_clip.DEFAULT_POSE`):
    ``(name, None)``, the policy off and home held at the clip's end, ramped to over
    ``--after-clip-blend`` s (default :data:`~sim2real.deploy.rig.after_clip.DEFAULT_POSE_RAMP_S`).

    Raises:
        ValueError: ``--operator``, ``--motion-playback`` or a second ``--policy`` given too, a
            ``--policy`` of that name, ``--envs`` other than 1, a negative ramp.
    """
    if DEFAULT_POSE in policies:
        raise ValueError(
            f"--policy {DEFAULT_POSE}=...: that name is --after-clip's hold at the home pose; "
            "name the policy otherwise"
        )
    for given, what in (
        (getattr(args, "operator", None), "--operator"),
        (args.motion_playback, f"--motion-playback {args.motion_playback}"),
        (len(policies) > 1 or None, f"a second --policy ({list(policies)[1:]})"),
    ):
        if given:
            raise ValueError(
                f"--after-clip {DEFAULT_POSE} and {what}: at the clip's end the policy is off "
                "and home held; give one of them"
            )
    if args.envs != 1:
        raise ValueError(
            f"--after-clip {DEFAULT_POSE}: one robot: --envs must be 1, got {args.envs}"
        )
    if args.after_clip_blend is None:
        args.after_clip_blend = DEFAULT_POSE_RAMP_S
    if not args.after_clip_blend >= 0.0:
        raise ValueError(f"--after-clip-blend {args.after_clip_blend}: expected s >= 0")
    return DEFAULT_POSE, None
