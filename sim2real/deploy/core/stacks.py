"""The other training and deployment stacks, one record each (:class:`Stack`), and their registry
(:data:`STACK_REGISTRY`): what the toolkit knows of rl_sar, holosoma, mjlab, Isaac Lab, Unitree's
deploy.yaml, legged_gym and its forks, BeyondMimic and RoboMimic_Deploy, each in one module of
:mod:`sim2real.stacks` (registered when the registry first lists them), a stack kept outside the
tree through an entry point of the group ``sim2real.stacks``.

A stack has every face of :data:`FACES`, each ``"module:attribute"`` (imported when a dispatch site
asks for it, from the room that implements it), the object itself, or :class:`Absent` with the
reason it has none: never silently missing. The dispatch sites ask the registry, not the stacks'
names: the contract chain (:func:`sim2real.deploy.spec.foreign.registry.read_contract`: ``detect``
then ``contract``, stacks tried by ``rank``), the clip formats
(:func:`sim2real.deploy.tasks.motion.formats.clip_formats`: ``clips``), the training domain
(:mod:`sim2real.eval.world.domain`: ``domain``), the push benchmark and the stacks' own loops
(``own_loop``), and the own loop a tracking run's hard-limit and self-collision ticks are judged
against (``tracking_loop``: :mod:`sim2real.eval.soak.own_loop_limits`, for the soak and
``deploy-run``). ``tests/test_stack_seams.py`` fails naming the stack and the face when a face
neither resolves nor is declared absent, or lives above the room that asks for it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

from sim2real.deploy.core.registry import Registry, load_target

#: A stack's faces, and what each is once resolved:
#: ``detect``: ``(OnnxFacts) -> bool``, whether a policy file is the stack's;
#: ``contract``: ``(OnnxFacts) -> ForeignContract``, its contract (ForeignFormatError when it
#: cannot be read); ``domain``: a :class:`DomainReader`; ``clips``: a tuple of
#: :class:`~sim2real.deploy.tasks.motion.formats.ClipFormat`; ``terrain``: the type its terrain
#: description is read into; ``own_loop``: the function that runs a policy in the stack's own loop;
#: ``tracking_loop``: a :class:`TrackingLoop`, the stack's own loop of a motion-tracking policy.
FACES = ("detect", "contract", "domain", "clips", "terrain", "own_loop", "tracking_loop")


@dataclass(frozen=True)
class Absent:
    """A face a stack does not have, and why (one sentence naming what the stack does instead)."""

    reason: str


@dataclass(frozen=True)
class DomainReader:
    """A stack's training-domain face.

    Attributes:
        what: For messages: ``"a legged_gym config (.py)"``.
        suffixes: The suffixes of the config files it reads (``(".py",)``); empty: none.
        read: ``(Path) -> str``: a config file's domain as a ranges file's TOML text; None: the
            stack writes none (``DomainError`` naming the file and key when it cannot be read).
        of_policy: ``(Path, metadata: dict) -> str | None``: the domain a policy file of the
            stack records (in its metadata or its run folder), None when it records none.
    """

    what: str
    suffixes: tuple[str, ...] = ()
    read: Callable | None = None
    of_policy: Callable | None = None


@dataclass(frozen=True)
class TrackingLoop:
    """A stack's own loop of a motion-tracking policy (a clip, or a phase-clocked dance): the
    reference a tracking run's hard-limit and self-collision ticks are judged against.

    Attributes:
        what: For messages: ``"rl_sar whole_body_tracking (the TorchScript policy.pt ...)"``.
        folder: ``(Path) -> Path | None``: the stack's policy folder a policy file (the ONNX
            export beside the stack's own file) sits in, None when it is not this loop's.
        play: ``(robot, folder, seed, seconds, pushes, watch, repeat=1) -> Run``: ``repeat``
            plays back to back of the folder's motion on ``robot``'s bare plant
            (:mod:`sim2real.stacks.loops.bare`), at most ``seconds`` s of it (None: all), under
            ``pushes`` (a :class:`~sim2real.eval.world.pushes.PushRanges` or None) seeded by
            ``seed``; ``watch(d, target)`` sees each tick's true ``mujoco.MjData`` and PD target
            (robot order, rad) before the physics steps. ``Run.walked``: s of motion played.
    """

    what: str
    folder: Callable
    play: Callable


@dataclass(frozen=True)
class Stack:
    """One stack (module docstring); every face of :data:`FACES` a field.

    Attributes:
        name: Its name (a contract's ``format``): ``"rl_sar"``. about: One line: what it is
            and the source its faces were written from (repository and commit).
        rank: Where its ``detect`` is tried, lowest first (metadata formats before those that
            read files beside a bare graph).
    """

    name: str
    about: str
    rank: int
    detect: object
    contract: object
    domain: object
    clips: object
    terrain: object
    own_loop: object
    tracking_loop: object

    def face(self, name: str):
        """The face ``name`` resolved (a ``"module:attribute"`` imported now), or None when the
        stack declares it :class:`Absent`.

        Raises:
            ValueError: ``name`` is no face of :data:`FACES`. ImportError, AttributeError: a
                target that does not resolve.
        """
        if name not in FACES:
            raise ValueError(f"stack face '{name}' is unknown; expected one of {FACES}")
        value = getattr(self, name)
        if isinstance(value, Absent):
            return None
        return load_target(value) if isinstance(value, str) else value


#: The registered stacks; the built-in ones (:mod:`sim2real.stacks`) register when it is first
#: listed, one kept outside the tree when its entry point (group ``sim2real.stacks``) is loaded.
STACK_REGISTRY: Registry[Stack] = Registry("stack", ("sim2real.stacks",), "sim2real.stacks")


def register_stack(stack: Stack) -> Stack:
    """Register ``stack`` under its name; returns it.

    Raises:
        ValueError: the name is registered already, or a face is neither a ``"module:attribute"``
            target, an object, nor :class:`Absent` (None: say why with ``Absent``).
    """
    for f in fields(stack):
        value = getattr(stack, f.name)
        if f.name in FACES and (value is None or (isinstance(value, str) and ":" not in value)):
            raise ValueError(
                f"stack '{stack.name}': face '{f.name}' = {value!r}: expected 'module:attribute',"
                " the face itself, or Absent(reason)"
            )
    return STACK_REGISTRY.register(stack.name, stack)


def stacks() -> tuple[Stack, ...]:
    """The registered stacks by ``rank`` (then name)."""
    return tuple(sorted(STACK_REGISTRY.entries().values(), key=lambda s: (s.rank, s.name)))


def with_face(name: str) -> tuple[tuple[Stack, object], ...]:
    """``(stack, resolved face)`` of every stack that has the face ``name``, by rank."""
    out = []
    for stack in stacks():
        face = stack.face(name)
        if face is not None:
            out.append((stack, face))
    return tuple(out)
