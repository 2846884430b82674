"""The plant of a soak batch: one randomized MuJoCo model per session in one batched plant, each
env's sensors set from its session's draw, streaming before the runtime starts.

:class:`sim2real.eval.soak.batch.SessionBatch` builds its plant here. Each env's model is the
robot's (or, with ``plant_motors``, the plant's motors' robot) randomized by its session's
:func:`~sim2real.eval.world.session_draw.sample_session` draw (dynamics, a legged robot's floor friction
and terrain tiles, a payload, a shifted centre of mass); its sensor noise comes from its own
seeded stream. Before
the runtime starts the plant streams its sensors for the largest latency the ranges allow plus
one encoder period, so that a reading has arrived (the same number of ticks for every session,
alone or batched).
"""

from __future__ import annotations

from sim2real.eval.world.dynamics import add_base_mass, randomized_model, shift_com
from sim2real.eval.world.floor import apply_floor_friction
from sim2real.eval.world.sensors import apply_imu, apply_sensors
from sim2real.eval.world.session_draw import session_rng
from sim2real.eval.world.terrain import apply_terrain


def build_plant(robot, mode: str, configs: list, draws: list) -> tuple:
    """The batch's plant, streaming, for ``configs`` (the sessions, same options but the seed).

    Args:
        robot: The robot the policy drives (its PD gains and default pose the policy's).
        mode: The policy's action mode (``"position"``, ``"velocity"``, ``"torque"``).
        configs: The sessions' :class:`~sim2real.eval.soak.session.SessionConfig`, one per env.
        draws: Their :func:`~sim2real.eval.world.session_draw.sample_session` draws, same order.

    Returns:
        ``(backend, models)``: the plant (``envs = len(configs)``) and its env's ``MjModel`` each.

    Raises:
        RobotSpecError: an unreadable ``plant_motors`` file
            (:func:`sim2real.robots.plant_motors.load_plant_motors`).
        ValueError: an engine whose package is not installed (naming the extra).
    """
    from sim2real.deploy.backends.sim.engines import make_plant
    from sim2real.robots.plant_motors import load_plant_motors

    first, k = configs[0], len(configs)
    # the motors as the plant simulates them (sim2real.robots.plant_motors), when they differ
    plant = None if first.plant_motors is None else load_plant_motors(first.plant_motors, robot)
    plant_robot = robot if plant is None else plant.robot
    grounds: list = [None] * k  # each env's ground on terrain (the truth's ground under it)

    def lay(e: int):
        d, seed = draws[e], configs[e].seed
        if d.terrain is None:
            return None

        def ground(spec) -> None:
            grounds[e] = apply_terrain(spec, d.terrain, session_rng(seed, "terrain_tiles"))

        return ground

    models = [randomized_model(plant_robot, mode, d.dynamics, lay(e)) for e, d in enumerate(draws)]
    if plant is not None:
        models = [plant.apply(m) for m in models]
    for m, d, c in zip(models, draws, configs, strict=True):
        if d.floor_friction is not None:  # a legged robot's floor
            apply_floor_friction(m, d.floor_friction)
        if d.added_base_mass is not None:  # a payload of its training domain
            body = getattr(c.ranges, "added_mass_body", "")  # default: the base
            add_base_mass(m, robot, d.added_base_mass, body)
        if d.com_offset is not None:  # a centre of mass off its nominal place
            shift_com(m, *d.com_offset)
    backend = make_plant(first.engine, plant_robot, mode=mode, envs=k, models=models)
    if any(g is not None for g in grounds):
        backend.grounds = grounds
    backend.set_sensor_streams([session_rng(c.seed, "sensor_noise") for c in configs])
    for e, d in enumerate(draws):
        apply_sensors(backend, e, d.sensors)
        backend.actuators.supply[e] = d.dynamics.supply  # the battery's charge
        if d.encoder_bias is not None:  # each encoder's calibration error
            backend.encoder_bias[e] = d.encoder_bias
        if d.imu is not None:  # a legged robot's IMU
            apply_imu(backend, e, d.imu)
    backend.reset()  # the first readings from the sessions' own streams and settings
    # the drives stream for a while before the runtime starts, so that a reading has arrived
    # despite the latency (the same number of ticks for every session, alone or batched)
    for _ in range(first.ranges.sensors.latency_ticks[1] + backend.encoder_every):
        backend.advance()
    return backend, models
