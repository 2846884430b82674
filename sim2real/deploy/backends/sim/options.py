"""``deploy-run --backend sim``: the simulated plant on MuJoCo or pybullet
(:mod:`sim2real.deploy.backends.registry`, :mod:`sim2real.deploy.backends.sim.engines`)."""

from __future__ import annotations

import numpy as np

from sim2real.deploy.backends.registry import register_backend
from sim2real.deploy.backends.sim.engines import add_engine_option, engines


def add_options(group) -> None:
    """``--engine``: the physics engine of the plant; ``--plant-motors``: its motors."""
    add_engine_option(group)
    add_plant_motors_option(group)


def add_plant_motors_option(group) -> None:
    """``--plant-motors FILE``: the motors as the plant simulates them (one option for
    deploy-run's sim backend, soak-test and the emulators)."""
    group.add_argument(
        "--plant-motors",
        default=None,
        metavar="FILE",
        help="the motors as the plant simulates them, when they differ from the robot's "
        "description (friction, armature, damping factors; motor fields such as command_delay "
        "and max_velocity): sim2real/robots/plant_motors.py",
    )


def plant_for(robot, mode: str, path: str | None, envs: int):
    """``(plant_robot, models)``: ``robot`` and None, or with a plant motors file ``path`` the
    robot with its motors replaced and ``envs`` plant models with its joint factors."""
    if path is None:
        return robot, None
    from sim2real.robots.plant_motors import load_plant_motors

    plant = load_plant_motors(path, robot)
    return plant.robot, [plant.apply(plant.robot.plant_model(mode)) for _ in range(envs)]


def make(args, robot, mode: str):
    """The plant for ``args.envs`` robots on ``args.engine``, its sensor streams seeded with
    ``args.seed``; with ``args.terrain`` (deploy-run ``--terrain``: a draw with ``apply(spec,
    rng) -> ground``, :class:`sim2real.eval.world.terrain.TerrainDraw`) each env's model on its
    ground, tiles drawn from ``args.seed``, and the plant's ``grounds`` set."""
    from sim2real.deploy.backends.sim.engines import make_plant

    engine = getattr(args, "engine", engines()[0])
    path = getattr(args, "plant_motors", None)
    plant_robot, models = plant_for(robot, mode, path, args.envs)
    terrain, grounds = getattr(args, "terrain", None), []
    if terrain is not None:
        models = []
        for e in range(args.envs):
            spec = plant_robot.mjspec(mode)
            grounds.append(terrain.apply(spec, np.random.default_rng([args.seed, e])))
            models.append(spec.compile())
        if path is not None:
            from sim2real.robots.plant_motors import load_plant_motors

            plant = load_plant_motors(path, robot)
            models = [plant.apply(m) for m in models]
    backend = make_plant(
        engine, plant_robot, mode=mode, envs=args.envs, seed=args.seed, models=models
    )
    if grounds:
        backend.grounds = grounds
    return backend


register_backend(
    "sim",
    "simulated plant (MuJoCo, or pybullet with --engine)",
    "sim2real.deploy.backends.sim.options:make",
    add_options,
)
