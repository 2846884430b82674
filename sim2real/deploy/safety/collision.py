"""The guard's collision geometry: the coal model of a robot's listed collision pairs
(:func:`collision_model`) and one query of it (:func:`collision_query`), shared by the guard, the
motion envelope and the violation monitor, so that all three agree on what contact is.
"""

from __future__ import annotations

import operator
import warnings

import numpy as np
import pinocchio as pin

from sim2real.robots import Robot


def collision_model(robot: Robot) -> tuple[pin.GeometryModel, pin.GeometryData]:
    """The guard's coal collision model of ``robot``: the MJCF geoms (nominal geometry) with
    the pairs of ``safety.collision_pairs``, and its data. Use it with ``robot.pin_model``
    (``pin.computeCollisions``; ``robot.fixed_base_model`` for a floating base);
    :class:`sim2real.deploy.monitors.violations.ViolationMonitor` checks the true
    configuration with it.

    Raises:
        ValueError: a listed geom is not in the MJCF (the message names robot.toml, the field
            and the geoms there are).
    """
    geom = pin.buildGeomFromMJCF(robot.pin_model, str(robot.mjcf_path), pin.VISUAL)
    geom = robot.fixed_base_geometry(geom)  # a floating base: the legs about a fixed base
    names = [g.name for g in geom.geometryObjects]
    for a, b in robot.config.safety.collision_pairs:
        for name in (a, b):
            if name not in names:
                raise ValueError(
                    f"{robot.directory / 'robot.toml'}: field 'safety.collision_pairs': geom "
                    f"'{name}' is not in {robot.mjcf_path.name} (geoms: {names})"
                )
        geom.addCollisionPair(pin.CollisionPair(names.index(a), names.index(b)))
    data = pin.GeometryData(geom)
    # Pinocchio's GeometryData warm-starts coal's GJK from the last query's result
    # (enable_cached_gjk_guess). The answer then depends on the query history: from a cached
    # guess coal reported no contact for arm6 pairs penetrating by 9 mm, which a fresh query
    # finds (tests/test_safety.py). Every query starts from coal's default guess instead.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the flag is deprecated in coal
        for request in [*data.collisionRequests, *data.distanceRequests]:
            request.enable_cached_gjk_guess = False
    return geom, data


def collision_query(
    model: pin.Model,
    data: pin.Data,
    geom_model: pin.GeometryModel,
    geom_data: pin.GeometryData,
    q: np.ndarray,
    distances: np.ndarray | None = None,
) -> bool:
    """Whether a collision pair of ``geom_model`` touches at ``q`` (rad; coal, stopping at the
    first contact). With ``distances`` ((pairs,) m, written), also each pair's distance there for
    the screens: all ``-inf`` when a pair touches (the screen then checks again next tick)."""
    hit = bool(pin.computeCollisions(model, data, geom_model, geom_data, q, True))
    if distances is not None:
        if hit:
            distances.fill(-np.inf)
        else:  # the placements at q, which computeCollisions has just updated
            pin.computeDistances(geom_model, geom_data)
            distances[:] = list(map(_MIN_DISTANCE, _distance_results(geom_data)))
    return hit


_MIN_DISTANCE = operator.attrgetter("min_distance")


def _distance_results(geom_data: pin.GeometryData) -> list:
    """``geom_data.distanceResults`` as a kept list of its proxies (made again if its length
    changed). Iterating the vector builds a proxy per pair on every pass, most of a walking
    robot's query; kept proxies read the vector's current entries. The list lives on the
    ``GeometryData`` itself, and goes with it."""
    kept = getattr(geom_data, "_kept_distance_results", None)
    if kept is None or len(kept) != len(geom_data.distanceResults):
        kept = list(geom_data.distanceResults)
        geom_data._kept_distance_results = kept
    return kept
