"""``deploy-run --backend sim``: the MuJoCo plant (:mod:`deploy.backends.registry`)."""

from __future__ import annotations

from deploy.backends.registry import register_backend


def make(args, robot, mode: str):
    """The plant for ``args.envs`` robots, its sensor streams seeded with ``args.seed``."""
    from deploy.backends.sim.plant import SimBackend

    return SimBackend(robot, mode=mode, envs=args.envs, seed=args.seed)


register_backend("sim", "MuJoCo plant", "deploy.backends.sim.options:make")
