"""``deploy-run --backend sim``: the simulated plant on MuJoCo or pybullet
(:mod:`deploy.backends.registry`, :mod:`deploy.backends.sim.engines`)."""

from __future__ import annotations

from deploy.backends.registry import register_backend
from deploy.backends.sim.engines import add_engine_option, engines


def add_options(group) -> None:
    """``--engine``: the physics engine of the plant."""
    add_engine_option(group)


def make(args, robot, mode: str):
    """The plant for ``args.envs`` robots on ``args.engine``, its sensor streams seeded with
    ``args.seed``."""
    from deploy.backends.sim.engines import make_plant

    engine = getattr(args, "engine", engines()[0])
    return make_plant(engine, robot, mode=mode, envs=args.envs, seed=args.seed)


register_backend(
    "sim",
    "simulated plant (MuJoCo, or pybullet with --engine)",
    "deploy.backends.sim.options:make",
    add_options,
)
