"""The physics engines the simulated plant runs on, by name: one switch for ``deploy-run``,
``soak-test`` and sim-to-sim (``--engine``).

- ``mujoco``: :class:`deploy.backends.sim.plant.SimBackend`, the engine the shipped policies are
  trained in (soft convex contacts, implicit drives, joint armature).
- ``pybullet``: :class:`deploy.backends.sim.bullet.plant.BulletBackend`, Bullet's multibody
  dynamics with rigid sequential-impulse contacts, built from the same compiled model (extra
  ``pybullet``).

Both take the same arguments and keep the same interfaces
(:class:`~deploy.core.backend.Backend`, :class:`~deploy.core.backend.SimulatedPlant`, the state
dict), so the runtime, monitors and reports do not know which one runs.
"""

from __future__ import annotations

#: The engine names, the default first.
ENGINES = ("mujoco", "pybullet")


def plant_class(engine: str):
    """The plant class of ``engine``.

    Raises:
        ValueError: an unknown engine, or pybullet not installed (naming the extra).
    """
    if engine == "mujoco":
        from deploy.backends.sim.plant import SimBackend

        return SimBackend
    if engine == "pybullet":
        try:
            from deploy.backends.sim.bullet.plant import BulletBackend
        except ImportError as exc:  # pragma: no cover - the extra is part of .[all]
            raise ValueError(
                "engine 'pybullet' needs the pybullet package: "
                "pip install 'sim2real-deploy[pybullet]'"
            ) from exc
        return BulletBackend
    raise ValueError(f"engine '{engine}' is unknown; expected one of {ENGINES}")


def make_plant(engine: str, robot, **kwargs):
    """The plant of ``robot`` on ``engine``; ``kwargs`` as
    :class:`~deploy.backends.sim.plant.SimBackend` (mode, envs, seed, models, max_latency_ticks).

    Raises:
        ValueError: an unknown engine (see :func:`plant_class`) or bad plant arguments.
    """
    return plant_class(engine)(robot, **kwargs)
