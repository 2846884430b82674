"""After-tick hooks: what a run adds to the runtime's ticks, each with its own part of the report.

A hook (:class:`RunHook`) is called after every control tick (:meth:`RunHook.after_tick`, which
may end the run by returning True), started with the run and closed after it, and writes its own
entries into the run's report (:meth:`RunHook.contribute`). The rig (:class:`sim2real.deploy.rig.Rig`)
calls them in the order they were added and times each.

Hooks a user switches on from the command line register here (:func:`register_hook`): a name,
a factory ``"module:function"`` called as ``factory(args, rig)`` (a hook, or None when its
options leave it off) and a function that adds its options to the parser. The built-in ones
register in the modules of :data:`BUILTIN`; a new hook is one module that calls
:func:`register_hook` and one line in :data:`BUILTIN` (or a call before the parser is built).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass

from sim2real.deploy.core.registry import Registry, check_target, load_target

#: Modules whose import registers the built-in command-line hooks (light: nothing heavy imported).
BUILTIN = ("sim2real.deploy.rig.builtin_hooks",)


class RunHook:
    """Base of an after-tick hook; every method is optional (the defaults do nothing).

    Attributes:
        name: The hook's name in the rig's per-hook cost (``hook_cost_us`` of the report).
    """

    name = "hook"

    def start(self, rig) -> None:
        """Called once when the run starts (after the runtime's start)."""

    def after_tick(self, runtime) -> bool | None:
        """Called after every control tick; True ends the run after this tick."""
        return None

    def close(self) -> None:
        """Called once after the run."""

    def discard(self) -> None:
        """Called instead of :meth:`close` when the run is refused or ends in an error: release
        what the hook holds and leave no partial output (default: :meth:`close`)."""
        self.close()

    def contribute(self, report: dict) -> None:
        """Write this hook's entries into the run's ``report`` (a JSON-ready dict)."""


@dataclass(frozen=True)
class HookEntry:
    """One registered command-line hook: ``name``, ``factory`` (``module:function``, called as
    ``factory(args, rig)``), ``add_options`` (adds its options to an argument group)."""

    name: str
    factory: str
    add_options: Callable[[argparse._ArgumentGroup], None] | None = None

    def build(self, args, rig) -> RunHook | None:
        """The hook for the parsed ``args`` (None: its options leave it off)."""
        return load_target(self.factory)(args, rig)


#: The registered command-line hooks (:class:`sim2real.deploy.core.registry.Registry`).
HOOK_REGISTRY: Registry[HookEntry] = Registry("hook", BUILTIN)


def register_hook(
    name: str,
    factory: str,
    add_options: Callable[[argparse._ArgumentGroup], None] | None = None,
) -> HookEntry:
    """Register a command-line hook under ``name`` (see the module docstring).

    Raises:
        ValueError: ``name`` is registered already, or ``factory`` is not ``module:function``.
    """
    check_target("hook", name, factory)
    return HOOK_REGISTRY.register(name, HookEntry(name, factory, add_options))


def registered_hooks() -> dict[str, HookEntry]:
    """The registered command-line hooks by name (the built-in ones first)."""
    return HOOK_REGISTRY.entries()


def add_hook_options(parser: argparse.ArgumentParser) -> None:
    """Add every registered hook's options to ``parser``."""
    for entry in registered_hooks().values():
        if entry.add_options is not None:
            entry.add_options(parser)


def build_hooks(args, rig) -> list[RunHook]:
    """The hooks the parsed ``args`` switch on, in registration order."""
    hooks = (entry.build(args, rig) for entry in registered_hooks().values())
    return [hook for hook in hooks if hook is not None]
