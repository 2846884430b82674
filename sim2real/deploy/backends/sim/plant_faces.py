"""The plant's extras of each robot kind, a face registered under the kind's name
(:class:`sim2real.deploy.core.registry.Faces`): what the simulated plant adds beside the joints'
sensors and drives. A floating base's IMU and foot contacts
(:class:`~sim2real.deploy.backends.sim.legged_sensors.BaseSensorModel`); an arm has none.
"""

from __future__ import annotations

from sim2real.deploy.backends.sim.legged_sensors import BaseSensorModel
from sim2real.deploy.core.registry import Faces
from sim2real.deploy.kinds import robot_kind


def no_extras(plant, robot) -> None:
    """An arm's extras: none."""
    return None


#: ``(plant, robot) -> BaseSensorModel | None`` of each robot kind, by its name.
PLANT_EXTRAS: Faces = Faces("plant's extras")
PLANT_EXTRAS.register("arm", no_extras)
PLANT_EXTRAS.register("legged", BaseSensorModel)


def plant_extras(plant, robot) -> BaseSensorModel | None:
    """The extras of ``plant`` (a :class:`~sim2real.deploy.backends.sim.plant.SimBackend` being
    built) that ``robot``'s kind registered (:data:`PLANT_EXTRAS`).

    Raises:
        ValueError: the robot's kind registered no plant extras."""
    return PLANT_EXTRAS.get(robot_kind(robot))(plant, robot)
