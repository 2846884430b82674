"""The ``policy-export`` command (:func:`main`; usage and formats in :mod:`sim2real.deploy.export`): its
exit statuses ``EXIT_*``, a bare SOURCE name looked up in ``sim2real/policies/``
(:func:`resolve_policy_path`), and ``--inspect`` through :mod:`sim2real.deploy.export.inspect_policy`.
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

from sim2real.deploy.export.errors import ExportError, ParityError
from sim2real.deploy.export.graph import EXPORTERS
from sim2real.deploy.export.noise_floor import describe_tolerance
from sim2real.deploy.export.pipeline import run_export
from sim2real.deploy.policy.mlp_checkpoint import ACTIVATIONS

EXIT_OK, EXIT_PARITY, EXIT_BAD_INPUT, EXIT_INTERNAL = 0, 1, 2, 3
POLICIES_DIR = Path(__file__).resolve().parents[2] / "policies"
R = TypeVar("R")


def resolve_policy_path(name: str | os.PathLike) -> Path:
    """``name`` if it exists, else ``sim2real/policies/<name>`` if that exists, else ``name``."""
    path = Path(name)
    if path.exists():
        return path
    candidate = POLICIES_DIR / path
    return candidate if candidate.exists() else path


def build_parser() -> argparse.ArgumentParser:
    """Return the parser of ``policy-export``'s options."""
    p = argparse.ArgumentParser(
        prog="policy-export",
        description="Export a trained policy to ONNX with its PolicySpec, after a parity check "
        "(ONNX Runtime vs torch on 1,000+ observations and a 1,000-tick closed-loop replay on the "
        "MuJoCo plant; max abs error <= max(1e-5, 4 x the source's float32 noise floor, measured "
        "by a float64 copy of the source). Exit status: 0 ok, 1 parity failure (the candidate "
        "kept as <stem>.parity-failed.onnx), 2 bad input; nothing is written under the output "
        "name unless every check passes.",
    )
    p.add_argument("source", help="policy file, or a name in sim2real/policies/")
    p.add_argument(
        "--spec",
        type=Path,
        help="PolicySpec JSON (required unless our checkpoint, or an ONNX file whose stack wrote "
        "its contract); with an ONNX file: stored in it instead of its own contract",
    )
    p.add_argument("--out", type=Path, help="ONNX file to write (default: beside SOURCE)")
    p.add_argument(
        "--trust-pickle", action="store_true", help="allow unpickling (runs code from the file)"
    )
    p.add_argument(
        "--vecnormalize", type=Path, help="SB3 VecNormalize statistics (.npz, .json, or .pkl)"
    )
    p.add_argument(
        "--activation", choices=sorted(ACTIVATIONS), help="override SB3/rsl_rl hidden activation"
    )
    p.add_argument("--robot", help="robot name or path (default: the spec's robot)")
    p.add_argument(
        "--from-config",
        type=Path,
        metavar="YAML",
        help="a legged_gym / unitree_rl_gym deploy config (kps, kds, default_angles, scales, ...) "
        "as the spec, instead of --spec; needs --robot DIR",
    )
    p.add_argument(
        "--write-robot",
        action="store_true",
        help="with --from-config: write the config's kps, kds and default_angles into the "
        "robot's robot.toml where they differ (without it a difference is refused)",
    )
    p.add_argument(
        "--domain",
        type=Path,
        metavar="FILE",
        help="the policy's training domain, stored in the ONNX file (metadata training_domain) "
        "for soak-test to run: a legged_gym config (.py, its domain_rand and noise classes, read "
        "as text) or a ranges file (.toml)",
    )
    p.add_argument(
        "--fps",
        type=float,
        help="a LeRobot policy folder: the policy's rate in Hz when its train_config.json has no "
        "env.fps (the dataset's meta/info.json fps)",
    )
    p.add_argument("--exporter", choices=EXPORTERS, default="torchscript")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--parity-tolerance",
        type=float,
        metavar="X",
        help="max abs error the parity gate accepts (actions and recurrent state); default "
        "max(1e-5, 4 x the source's float32 noise floor)",
    )
    p.add_argument(
        "--inspect",
        action="store_true",
        help="print what SOURCE is (ONNX or any input format: inputs, outputs, recurrent state, "
        "metadata, spec; a training stack's own contract, mapped onto --robot when given) and "
        "exit without exporting",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """The ``policy-export`` command; returns the exit status (0 ok, 1 parity failure, 2 bad
    input, 3 internal error)."""
    args = build_parser().parse_args(argv)
    source = resolve_policy_path(args.source)
    if not source.exists() and not source.is_absolute():
        print(
            f"policy-export: error: {source}: no such file (nor in {POLICIES_DIR})",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    from sim2real.deploy.spec.foreign import lerobot

    if args.inspect and lerobot.detect(source):
        try:
            contract = lerobot.read(source, fps=args.fps)
        except ValueError as exc:
            print(f"policy-export: error: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        print("\n".join(lerobot.describe(contract)))
        return EXIT_OK
    if args.inspect:
        return _inspect(source, args)
    if source.suffix.lower() == ".onnx":
        return _export_onnx(source, args)
    if lerobot.detect(source):
        return _export_lerobot(source, args)
    if _folder_route(args):
        return _export_folder(source, args)
    return _export_checkpoint(source, args)


def _folder_route(args) -> bool:
    """No spec given (``--spec``, ``--from-config``) nor a rebuilt network's options: a
    TorchScript file may take its folder's contract (:mod:`sim2real.deploy.export.folder_torchscript`)."""
    return (
        args.spec is None
        and args.from_config is None
        and not args.write_robot
        and args.vecnormalize is None
        and args.activation is None
    )


def _export_folder(source: Path, args) -> int:
    """A TorchScript file beside its stack's contract files (rl_sar's config.yaml): the bare
    graph beside it, after the parity gate; any other file goes on to :func:`_export_checkpoint`."""
    from sim2real.deploy.export.folder_torchscript import (
        export_folder_torchscript,
        folder_contract,
    )
    from sim2real.robots import load_robot

    def export():
        contract = folder_contract(source)
        if contract is None:
            return None
        if args.domain is not None or args.exporter != "torchscript":
            flag = "--domain" if args.domain is not None else "--exporter dynamo"
            raise ExportError(
                f"{source}: {flag} does not apply to the bare graph its {contract.format} "
                f"contract is read beside; export it first, then `policy-export "
                f"{source.with_suffix('.onnx')} --robot ROBOT {flag} ...`"
            )
        robot = load_robot(args.robot) if args.robot else None
        return export_folder_torchscript(
            source, args.out, robot, args.seed, args.parity_tolerance, contract
        )

    result = _exported(export)
    if isinstance(result, int):
        return result
    if result is None:
        return _export_checkpoint(source, args)
    c, f = result.contract, result.parity
    print(f"exported {source} (torchscript, {c.format} contract) -> {result.path}")
    print(
        f"  a bare graph: obs (1, {result.obs_dim}) -> actions (1, {result.act_dim}), no "
        f"policy_spec: the runtime reads the {c.format} contract beside it ({c.source})"
    )
    print(
        f"  parity: max |onnx - torch| {f['max_abs_error']:.2e} over {f['samples']} "
        f"observations, batch 1; {describe_tolerance(f)}"
    )
    if "replay_max_abs_error" in f:
        print(
            f"  closed-loop replay on {args.robot} ({f['replay_ticks']} ticks, "
            f"{f['replay_envs']} env): max |onnx - torch| {f['replay_max_abs_error']:.2e}; "
            f"{describe_tolerance(f, 'replay_', f.get('tolerance_note', ''))}"
        )
    print(f"  export time {result.seconds:.2f} s; {result.exporter}")
    print(f"  run: deploy-run --robot {args.robot or 'ROBOT'} --policy {result.path}")
    return EXIT_OK


def _export_lerobot(source: Path, args) -> int:
    """A LeRobot policy folder (``pretrained_model/``): its ACT or Diffusion Policy graph with the
    contract, after the parity check against lerobot's ``select_action``
    (:mod:`sim2real.deploy.export.lerobot_act`, :mod:`sim2real.deploy.export.lerobot_diffusion`)."""

    def export():
        from sim2real.deploy.export.lerobot_act import export_lerobot_act
        from sim2real.deploy.spec.foreign.lerobot import read

        if args.robot:
            from sim2real.robots import load_robot

            joints = load_robot(args.robot).joint_names
            c = read(source, fps=args.fps)
            if c.action_dim != len(joints) or c.state_dim != len(joints):
                raise ExportError(
                    f"{source / 'config.json'}: observation.state has {c.state_dim} and action "
                    f"{c.action_dim} entries, robot {args.robot} has {len(joints)} joints"
                )
        run = export_lerobot_act
        if read(source, fps=args.fps).policy_type == "diffusion":
            from sim2real.deploy.export.lerobot_diffusion import export_lerobot_diffusion as run
        return run(source, args.out, fps=args.fps, robot=args.robot, seed=args.seed)

    result = _exported(export)
    if isinstance(result, int):
        return result
    from sim2real.deploy.spec.foreign.lerobot import describe

    c = result.contract
    print(f"exported {source} (lerobot {c.policy_type}) -> {result.path}")
    for line in describe(c):
        print(f"  {line}")
    print(
        f"  parity vs lerobot's select_action: max |onnx - lerobot| {result.max_abs_error:.2e} "
        f"(action units), {result.max_rel_error:.2e} of the action's scale, over {result.ticks} "
        f"ticks and {result.calls} network calls"
    )
    print(f"  export time {result.seconds:.2f} s")
    return EXIT_OK


def _inspect(source: Path, args) -> int:
    """Print what ``source`` is (``--inspect``); return the exit status."""
    from sim2real.deploy.export.errors import InspectError
    from sim2real.deploy.export.inspect_policy import inspect_file
    from sim2real.deploy.export.inspect_report import format_report

    try:
        robot = None
        if args.robot:
            from sim2real.robots import load_robot

            robot = load_robot(args.robot)
        print(format_report(inspect_file(source, robot)))
    except (InspectError, ValueError) as exc:  # RobotSpecError is a ValueError
        print(f"policy-export: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return EXIT_OK


def _export_checkpoint(source: Path, args) -> int:
    """Export a torch checkpoint and print what was written; return the exit status."""

    def export():
        spec, robot, notes = args.spec, args.robot, []
        if args.from_config is not None or args.write_robot:
            spec, robot, notes = _from_config(args)
        metadata = _domain(args, robot) if args.domain is not None else None
        result = run_export(
            source,
            out=args.out,
            spec=spec,
            trust_pickle=args.trust_pickle,
            vecnormalize=args.vecnormalize,
            activation=args.activation,
            robot=robot,
            exporter=args.exporter,
            seed=args.seed,
            tolerance=args.parity_tolerance,
            metadata=metadata,
        )
        return result, notes, metadata

    outcome = _exported(export, bad_input=(ExportError,))
    if isinstance(outcome, int):
        return outcome
    result, notes, metadata = outcome
    _print_export(source, args, result, notes, metadata)
    return EXIT_OK


def _print_export(
    source: Path, args, result, notes: list[str], metadata: dict[str, str] | None
) -> None:
    """Print the notes, the file written, its spec, parity, export time and how to run it."""
    s, f = result.spec, result.parity
    baked = [k.replace("_", " ") for k, v in s.baked.items() if v]
    for line in notes:
        print(line)
    print(f"exported {source} ({result.source_format}) -> {result.path}")
    print(
        f"  robot {s.robot}, {s.action.mode} mode at {s.control_rate:g} Hz; obs {s.obs_dim} -> "
        f"action {s.act_dim}; baked: {', '.join(baked) or 'nothing'}"
    )
    print(
        f"  parity: max |onnx - torch| {f['max_abs_error']:.2e} over {f['samples']} observations; "
        f"{describe_tolerance(f)}"
    )
    print(
        f"  closed-loop replay ({f['replay_ticks']} ticks, {f['replay_envs']} envs): max |onnx - "
        f"torch| {f['replay_max_abs_error']:.2e}; "
        f"{describe_tolerance(f, 'replay_', f.get('tolerance_note', ''))}"
    )
    if "state_max_abs_error" in f:
        print(
            f"  recurrent state: max |onnx - torch| {f['state_max_abs_error']:.2e}; "
            f"{describe_tolerance(f, 'state_', f.get('tolerance_note', ''))}"
        )
    print(f"  export time {result.seconds:.2f} s; {result.exporter}")
    if metadata is not None:
        print(f"  training domain from {args.domain} (soak-test runs it; metadata training_domain)")
    if args.from_config is not None:
        blocks = ", ".join(b.name for b in s.observation_blocks)
        print(f"  spec from {args.from_config}: {blocks}; joints {', '.join(s.joint_names)}")
        command = _command_init(args.from_config)
        print(
            f"  run: deploy-run --robot {args.robot} --policy {result.path}"
            + (f" --command {command}" if command else "")
        )


def _export_onnx(source: Path, args) -> int:
    """A foreign ONNX policy written for ``--robot`` with our spec (``onnx_source``)."""
    from sim2real.deploy.export.onnx_source import export_onnx_policy
    from sim2real.robots import load_robot

    def export():
        if args.from_config is not None:
            raise ExportError(
                f"{source}: --from-config is for a torch checkpoint; an ONNX policy takes its "
                "spec from its own contract or from --spec FILE"
            )
        if "policy_spec" in _onnx_metadata(source):
            raise ExportError(
                f"{source}: already an ONNX file with its policy_spec (our own export); nothing "
                "to add (export takes a torch checkpoint, or another stack's ONNX)"
            )
        robot = args.robot or (_spec_robot(args.spec) if args.spec is not None else None)
        if robot is None:
            raise ExportError(
                f"{source}: an ONNX policy needs --robot DIR (the robot its contract maps onto)"
            )
        the_robot = load_robot(robot)
        metadata = _domain(args, the_robot) if args.domain is not None else None
        result = export_onnx_policy(
            source, the_robot, args.out, args.seed, args.spec, metadata=metadata
        )
        return result, robot

    outcome = _exported(export)
    if isinstance(outcome, int):
        return outcome
    result, robot = outcome
    s, f = result.spec, result.parity
    print(f"exported {source} ({result.source_format}) -> {result.path}")
    print(
        f"  robot {s.robot}, {s.action.mode} mode at {s.control_rate:g} Hz; obs {s.obs_dim} -> "
        f"action {s.act_dim}; the source graph unchanged, weights inlined, our spec in its metadata"
    )
    print(
        f"  parity: max |written - source| {f['max_abs_error']:.1e} over {f['samples']} "
        "observations (ONNX Runtime on both files; exact)"
    )
    if args.spec is not None:
        print(f"  spec from {args.spec} (the file's own contract, if any, not read)")
    if args.domain is not None:
        print(f"  training domain from {args.domain} (soak-test runs it; metadata training_domain)")
    print(f"  run: deploy-run --robot {robot} --policy {result.path}")
    return EXIT_OK


def _exported(
    export: Callable[[], R], bad_input: tuple[type[Exception], ...] = (ExportError, ValueError)
) -> R | int:
    """``export()``'s result, or the exit status after saying on stderr why there is none: a
    parity failure (``EXIT_PARITY``), an input refused with one of ``bad_input`` (``EXIT_BAD_INPUT``;
    a RobotSpecError is a ValueError) or a bug (its traceback, ``EXIT_INTERNAL``). ``export``
    returns anything but an int."""
    try:
        return export()
    except ParityError as exc:
        print(f"policy-export: parity check FAILED: {exc}", file=sys.stderr)
        return EXIT_PARITY
    except bad_input as exc:
        print(f"policy-export: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception:  # noqa: BLE001 - a bug, not bad input nor a parity failure
        traceback.print_exc()
        print("policy-export: internal error (see the traceback above)", file=sys.stderr)
        return EXIT_INTERNAL


def _spec_robot(path: Path) -> str:
    """The robot a spec file names (``--robot``'s default with ``--spec``).

    Raises:
        ExportError: the file cannot be read as a spec (naming it and the field).
    """
    from sim2real.deploy.policy.onnx_spec import read_spec
    from sim2real.deploy.spec.policy_spec import SpecError

    try:
        return read_spec(path).robot
    except SpecError as exc:
        raise ExportError(str(exc)) from None


def _onnx_metadata(path: Path) -> dict[str, str]:
    """The ONNX file's metadata (its weights not read).

    Raises:
        ExportError: not a readable ONNX model (the message of
            :func:`sim2real.deploy.spec.onnx_checks.read_model`).
    """
    from sim2real.deploy.spec.onnx_checks import PolicyLoadError, read_model

    try:
        model = read_model(path)
    except PolicyLoadError as exc:
        raise ExportError(str(exc)) from None
    return {p.key: p.value for p in model.metadata_props}


def _domain(args, robot) -> dict[str, str]:
    """``--domain``: the metadata entry of the training domain, checked against the robot.

    Raises:
        ExportError: a source that is not a legged_gym config or a ranges file, or whose ranges
            the robot refuses (named).
    """
    from sim2real.eval.world.domain import METADATA_KEY, DomainError, domain_toml
    from sim2real.eval.world.ranges_file import RangesError, load_ranges_text
    from sim2real.robots import load_robot

    try:
        text = domain_toml(args.domain)
        if robot is not None:
            the_robot = load_robot(robot) if isinstance(robot, (str, Path)) else robot
            load_ranges_text(text, str(args.domain), the_robot)
    except (DomainError, RangesError) as exc:
        raise ExportError(f"--domain: {exc}") from None
    return {METADATA_KEY: text}


def _from_config(args):
    """``--from-config`` / ``--write-robot``: (spec, robot, notes) of
    :func:`sim2real.deploy.export.deploy_config.spec_and_robot`.

    Raises:
        ExportError: the flags do not go together, or the config or robot is refused.
    """
    from sim2real.deploy.export.deploy_config import spec_and_robot

    if args.from_config is None:
        raise ExportError("--write-robot goes with --from-config")
    if args.spec is not None:
        raise ExportError("--from-config and --spec both give the spec: pass one of them")
    if args.robot is None:
        raise ExportError("--from-config needs --robot DIR (the robot folder the config is for)")
    return spec_and_robot(args.from_config, args.robot, args.write_robot)


def _command_init(path: Path) -> str:
    """The config's ``cmd_init`` as ``VX,VY,WZ`` (empty without one)."""
    from sim2real.deploy.export.deploy_config import read_config

    cmd = read_config(path).cmd_init
    return "" if cmd is None else ",".join(f"{c:g}" for c in cmd)


if __name__ == "__main__":  # python -m sim2real.deploy.cli.policy_export, as policy-export
    raise SystemExit(main())
