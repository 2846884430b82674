"""What the factories of the backends that drive one real robot share
(:mod:`sim2real.deploy.backends.registry`): the simulation-only options they refuse."""

from __future__ import annotations


def refuse_simulation_options(args, backend: str, faults: str) -> None:
    """Refuse deploy-run's simulation-only options for ``--backend <backend>``.

    Args:
        args: deploy-run's parsed options (``envs``, ``inject``).
        backend: The backend's name. faults: How its emulator injects faults instead (a command
            line, for the message).

    Raises:
        ValueError: ``--envs`` other than 1 (one robot), or ``--inject`` given.
    """
    if args.envs != 1:
        raise ValueError(f"--backend {backend} drives one robot: --envs must be 1")
    if args.inject:
        raise ValueError(
            f"--inject is simulation-only; with --backend {backend} use the emulator's faults "
            f"({faults})"
        )
