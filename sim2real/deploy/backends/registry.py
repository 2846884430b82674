"""The backends ``deploy-run --backend NAME`` can drive: one registration each, with its own
command-line options.

A backend registers (:func:`register_backend`) its name, a one-line description, its factory
(``"module:function"``, imported only when the backend is built, so that parsing the command line
imports neither MuJoCo nor a vendor SDK) and a function that adds its options to the parser.
``deploy-run --backend NAME --help`` lists that backend's options. The built-in backends register
in the modules of :data:`BUILTIN`; a new backend is one more module there (or a call of
:func:`register_backend` before :func:`sim2real.deploy.cli.deploy_run.deploy_run_main` runs).

A factory is called as ``factory(args, robot, mode)`` (the parsed options, the
:class:`~robots.Robot`, the policy's control mode) and returns an unopened
:class:`~sim2real.deploy.core.backend.Backend`; it raises ``ValueError`` for options it cannot honour.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass

from sim2real.deploy.core.registry import Registry, check_target, load_target

#: Modules of this room whose import registers the built-in backends (light: no MuJoCo, no
#: SDK); the ros2 backend lives a floor above and registers when deploy-run's parser imports it
#: (:mod:`sim2real.deploy.cli.run_parser`).
BUILTIN = (
    "sim2real.deploy.backends.sim.options",
    "sim2real.deploy.backends.servo.options",
    "sim2real.deploy.backends.unitree.options",
)


@dataclass(frozen=True)
class BackendEntry:
    """One registered backend: ``name``, ``help`` (one line), ``factory`` (``module:function``),
    ``add_options`` (adds its options to an argument group; may be None)."""

    name: str
    help: str
    factory: str
    add_options: Callable[[argparse._ArgumentGroup], None] | None = None

    def build(self, args, robot, mode: str):
        """The backend, not yet opened (the factory's errors propagate)."""
        return load_target(self.factory)(args, robot, mode)


#: The registered backends (:class:`sim2real.deploy.core.registry.Registry`).
BACKEND_REGISTRY: Registry[BackendEntry] = Registry("backend", BUILTIN)


def register_backend(
    name: str,
    help: str,
    factory: str,
    add_options: Callable[[argparse._ArgumentGroup], None] | None = None,
) -> BackendEntry:
    """Register a backend under ``name`` (see the module docstring).

    Raises:
        ValueError: ``name`` is registered already, or ``factory`` is not ``module:function``.
    """
    check_target("backend", name, factory)
    return BACKEND_REGISTRY.register(name, BackendEntry(name, help, factory, add_options))


def backends() -> dict[str, BackendEntry]:
    """The registered backends by name (the built-in ones registered first)."""
    return BACKEND_REGISTRY.entries()


def add_backend_options(parser: argparse.ArgumentParser, argv: list[str] | None) -> None:
    """Add ``--backend`` and the options of the backend ``argv`` chooses (``sim`` by default),
    in a group titled after it, to ``parser``."""
    entries = backends()
    parser.add_argument(
        "--backend",
        choices=tuple(entries),
        default="sim",
        help="; ".join(f"{e.name}: {e.help}" for e in entries.values()),
    )
    probe = argparse.ArgumentParser(add_help=False)
    probe.add_argument("--backend", default="sim")
    chosen = probe.parse_known_args(argv)[0].backend
    entry = entries.get(chosen)
    if entry is not None and entry.add_options is not None:
        entry.add_options(parser.add_argument_group(f"--backend {chosen}"))


def make_backend(args, robot, mode: str):
    """The backend ``args.backend`` names, built by its factory (not yet opened).

    Raises:
        ValueError: an unknown backend, or options the backend cannot honour.
    """
    entries = backends()
    if args.backend not in entries:
        raise ValueError(f"--backend {args.backend}: expected one of {tuple(entries)}")
    return entries[args.backend].build(args, robot, mode)
