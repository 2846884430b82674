"""A policy's training domain: the world it was trained in, as a ranges file
(:mod:`sim2real.eval.world.ranges_file`), so that the soak runs that world plus its own faults.

Where it comes from:

- **legged_gym** (unitree_rl_gym, HIMLoco, humanoid-gym and their forks): the task's config class,
  a Python file such as ``legged_gym/envs/h1/h1_config.py`` in its own tree, read as text with
  everything it inherits (:mod:`sim2real.eval.world.legged_gym_tree`) by
  :func:`sim2real.eval.world.legged_gym_domain.legged_gym_domain`: every value with the file and
  line it came from, every key the soak does not model named in one line
  (:func:`domain_account` gives those lines).
- **another stack's own record** (holosoma's ``experiment_config``, an Isaac Lab or mjlab run
  folder's ``params/env.yaml``): the ``domain`` face of the stack that recognises the policy
  (:mod:`sim2real.stacks`), read by :func:`training_domain` and :func:`domain_toml`.
- **a ranges file** (TOML) written by hand, or by :func:`domain_toml`.
- **our own recipes**: they train on the soak's own ranges (:func:`sim2real.eval.world.session_ranges.
  session_ranges`), which is what ``soak-test`` runs without a domain.

``policy-export --domain FILE`` stores the domain in the ONNX file (metadata ``training_domain``,
:data:`METADATA_KEY`: the ranges file's text); ``soak-test`` runs it when no ``--ranges`` is given.
"""

from __future__ import annotations

from pathlib import Path

from sim2real.eval.world.legged_gym_domain import (  # noqa: F401 - this module's names too
    DomainError,
    legged_gym_domain,
    read_legged_gym_config,
)

#: The ONNX metadata key of a policy's training domain (a ranges file's TOML text).
METADATA_KEY = "training_domain"
#: The comment lines of a stored domain that account for it
#: (:mod:`sim2real.eval.world.legged_gym_lines`): a value and where it came from, a key the soak
#: does not model, a randomization the training had off.
ACCOUNT_PREFIXES = ("# from: ", "# not modelled: ", "# off: ")


def domain_account(text: str) -> list[str]:
    """The account of a stored training domain (a ranges file's TOML ``text``): its lines that
    say where each value came from and what the soak does not model (:data:`ACCOUNT_PREFIXES`),
    in the file's order; empty for a domain written without one (a hand-written ranges file,
    an env.yaml's)."""
    return [line for line in text.splitlines() if line.startswith(ACCOUNT_PREFIXES)]


def domain_toml(path: str | Path) -> str:
    """The ranges file (TOML text) of a training-domain source: a config file of a stack whose
    ``domain`` face reads its suffix (:mod:`sim2real.stacks`: a legged_gym config ``.py``, an
    Isaac Lab or mjlab ``env.yaml``), or a ranges file (``.toml``) as it is.

    Raises:
        DomainError: a suffix no stack reads, or a source that cannot be read or has a
            randomization the soak cannot run (named).
    """
    path = Path(path)
    if path.suffix == ".toml":
        try:
            return path.read_text(encoding="utf-8")
        except OSError as exc:
            raise DomainError(f"{path}: cannot read the ranges file ({exc.strerror})") from None
    readers = _config_readers()
    for reader in readers:
        if path.suffix in reader.suffixes:
            return reader.read(path)
    known = ", ".join(r.what for r in readers)
    raise DomainError(f"{path}: a training domain is {known} or a ranges file (.toml)")


def _config_readers() -> list:
    """The stacks' domain faces that read a config file, each once (stacks by rank)."""
    from sim2real.deploy.core.stacks import with_face

    out = []
    for _, reader in with_face("domain"):
        if reader.read is not None and reader.suffixes and reader not in out:
            out.append(reader)
    return out


def training_domain(policy: str | Path) -> str | None:
    """The training domain of an ONNX policy: the one it carries (metadata ``training_domain``,
    the text of a ranges file), else, for a file without our spec, the one its stack records:
    the stack that recognises the file (the contract's ``detect``, :mod:`sim2real.stacks`) and
    its ``domain`` face (holosoma's ``experiment_config``; Isaac Lab's, mjlab's and Unitree's
    deploy.yaml's run folder's ``params/env.yaml`` when it has ``events``); None when no stack
    recognises the file or its stack records none.

    Raises:
        DomainError: the file cannot be read as ONNX, or the domain it records cannot be read
            or has a randomization the soak cannot run (named; ``soak-test --no-domain`` runs
            the robot kind's ranges instead).
    """
    import onnx

    from sim2real.deploy.spec.foreign.registry import OnnxFacts, detect_stack

    try:
        model = onnx.load(str(policy), load_external_data=False)
    except Exception as exc:  # noqa: BLE001 - onnx raises OSError, DecodeError, ...
        raise DomainError(f"{policy}: cannot read the ONNX file's metadata ({exc})") from None
    metadata = {p.key: p.value for p in model.metadata_props}
    if METADATA_KEY in metadata:
        return metadata[METADATA_KEY]
    if "policy_spec" in metadata:
        return None
    stack = detect_stack(OnnxFacts.of(policy, model))
    reader = None if stack is None else stack.face("domain")
    if reader is None or reader.of_policy is None:
        return None
    return reader.of_policy(Path(policy), metadata)


#: The metadata key of a velocity command's training ranges: holosoma's (``lin_vel_x``,
#: ``lin_vel_y``, ``ang_vel_yaw`` or ``ang_vel_z`` as ``[low, high]``, JSON), which
#: ``policy-export`` also writes for a policy whose contract records them.
COMMAND_RANGES_KEY = "command_ranges"


def contract_commands(policy: str | Path, strict: bool = True):
    """The velocity commands a policy trained elsewhere was trained on: from the contract its
    stack wrote (:mod:`sim2real.deploy.spec.foreign`: Unitree's deploy.yaml ``commands.base_velocity.
    ranges``, holosoma's ``command_ranges``), else from the file's ``command_ranges`` metadata
    (:data:`COMMAND_RANGES_KEY`: holosoma's, or what ``policy-export`` kept of the contract):
    ``(CommandRanges, where)``, or ``(None, None)`` when none is recorded. The fraction of zero
    commands stays :class:`~sim2real.deploy.tasks.commands.CommandRanges`' default.

    Args:
        policy: The ONNX file.
        strict: A contract that cannot be read is an error; False (a policy run with ``--spec``,
            whose contract need not map): only its metadata is read then.

    Raises:
        DomainError: the file cannot be read as ONNX, or (``strict``) its contract cannot be
            read (named).
    """
    import json

    import onnx

    from sim2real.deploy.spec.foreign.contract import command_ranges
    from sim2real.deploy.spec.foreign.registry import OnnxFacts, read_contract
    from sim2real.deploy.spec.policy_spec import SpecError
    from sim2real.deploy.tasks.commands import CommandRanges

    try:
        model = onnx.load(str(policy), load_external_data=False)
    except Exception as exc:  # noqa: BLE001 - onnx raises OSError, DecodeError, ...
        raise DomainError(f"{policy}: cannot read the ONNX file ({exc})") from None
    metadata = {p.key: p.value for p in model.metadata_props}
    ranges, source = None, None
    if "policy_spec" not in metadata:
        try:
            contract = read_contract(OnnxFacts.of(policy, model))
        except SpecError as exc:
            if strict:
                raise DomainError(str(exc)) from None
            contract = None
        if contract is not None and contract.command_ranges is not None:
            ranges, source = contract.command_ranges, contract.source
    if ranges is None and COMMAND_RANGES_KEY in metadata:
        try:
            ranges = command_ranges(json.loads(metadata[COMMAND_RANGES_KEY]))
        except json.JSONDecodeError:
            ranges = None
        source = f"{policy}: metadata '{COMMAND_RANGES_KEY}'"
    if ranges is None:
        return None, None
    return CommandRanges(vx=ranges["vx"], vy=ranges["vy"], yaw_rate=ranges["yaw_rate"]), source
