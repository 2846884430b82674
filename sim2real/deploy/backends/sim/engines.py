"""The physics engines the simulated plant runs on, by name: one registry and one ``--engine``
option for ``deploy-run``, ``soak-test`` and sim-to-sim.

- ``mujoco``: :class:`sim2real.deploy.backends.sim.plant.SimBackend`, the engine the shipped policies are
  trained in (soft convex contacts, implicit drives, joint armature).
- ``pybullet``: :class:`sim2real.deploy.backends.sim.bullet.plant.BulletBackend`, Bullet's multibody
  dynamics with rigid sequential-impulse contacts, built from the same compiled model (extra
  ``pybullet``).

An engine is a plant class that keeps the plant's interfaces
(:class:`~sim2real.deploy.core.backend.Backend`, :class:`~sim2real.deploy.core.backend.SimulatedPlant`, the
state dict) and takes :class:`~sim2real.deploy.backends.sim.plant.SimBackend`'s arguments, so the runtime,
monitors and reports do not know which one runs. A new engine is one module with its plant class
and one line in :data:`BUILTIN_ENGINES` (or a call of :func:`register_engine` before the command
line is parsed); the class is imported only when a plant is built.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim2real.deploy.core.registry import Registry, check_target, load_target


@dataclass(frozen=True)
class Engine:
    """One registered engine: ``name``, its plant class as ``"module:Class"`` and the
    ``pip`` extra that installs it (None: the core install)."""

    name: str
    plant: str
    extra: str | None = None

    def plant_class(self) -> type:
        """The plant class (imported now).

        Raises:
            ValueError: the engine's package is not installed (naming the extra).
        """
        try:
            return load_target(self.plant)
        except ImportError as exc:
            if self.extra is None:
                raise
            raise ValueError(
                f"engine '{self.name}' needs the extra '{self.extra}': "
                f"pip install 'sim2real-deploy[{self.extra}]' ({exc})"
            ) from exc


#: The built-in engines, the default first: name -> (plant class, extra).
BUILTIN_ENGINES = {
    "mujoco": ("sim2real.deploy.backends.sim.plant:SimBackend", None),
    "pybullet": ("sim2real.deploy.backends.sim.bullet.plant:BulletBackend", "pybullet"),
}

#: The registered engines (:class:`sim2real.deploy.core.registry.Registry`).
ENGINE_REGISTRY: Registry[Engine] = Registry("engine")


def register_engine(name: str, plant: str, extra: str | None = None) -> Engine:
    """Register an engine under ``name``: ``plant`` is its plant class as ``"module:Class"``.

    Raises:
        ValueError: ``name`` is registered already, or ``plant`` is not ``module:Class``.
    """
    check_target("engine", name, plant)
    return ENGINE_REGISTRY.register(name, Engine(name, plant, extra))


for _name, (_plant, _extra) in BUILTIN_ENGINES.items():
    register_engine(_name, _plant, _extra)

#: The engine names at import, the default first (see :func:`engines` for those added since).
ENGINES = ENGINE_REGISTRY.names()


def engines() -> tuple[str, ...]:
    """The registered engine names, the default (``mujoco``) first."""
    return ENGINE_REGISTRY.names()


def add_engine_option(parser, help_tail: str = "") -> None:
    """Add the one ``--engine`` option (choices: the registered engines; default mujoco) to
    ``parser`` (an ``ArgumentParser`` or an argument group)."""
    parser.add_argument(
        "--engine",
        choices=engines(),
        default=engines()[0],
        help="physics engine of the simulated plant (default mujoco; pybullet: a second "
        "opinion with rigid contacts, sim-to-sim)" + help_tail,
    )


def plant_class(engine: str) -> type:
    """The plant class of ``engine``.

    Raises:
        ValueError: an unknown engine, or its package not installed (naming the extra).
    """
    return ENGINE_REGISTRY.get(engine).plant_class()


def make_plant(engine: str, robot, **kwargs):
    """The plant of ``robot`` on ``engine``; ``kwargs`` as
    :class:`~sim2real.deploy.backends.sim.plant.SimBackend` (mode, envs, seed, models, max_latency_ticks).

    Raises:
        ValueError: an unknown engine (see :func:`plant_class`) or bad plant arguments.
    """
    return plant_class(engine)(robot, **kwargs)
