"""What the soak's world does to a robot of each kind (:data:`WORLD_OF_KIND`, a face registered
under the kind's name in this room, :class:`sim2real.deploy.core.registry.Faces`): whether the
training domain's pushes reach it (:meth:`TetheredWorld.domain_pushes`) and which fault kinds
it refuses (:meth:`TetheredWorld.refused_faults`).

A fixed base on its cable (an arm, :class:`TetheredWorld`) takes cable pulls and no domain
pushes; a free base (a legged robot, :class:`FreeWorld`) is pushed as its policy's training
domain pushed it (legged_gym's ``push_robots``) and has no cable to pull.
"""

from __future__ import annotations

from sim2real.deploy.core.registry import Faces


class TetheredWorld:
    """A fixed base's world: its cable is pulled, nothing pushes its base."""

    def domain_pushes(self, ranges):
        """The training domain's pushes of ``ranges`` (a
        :class:`~sim2real.eval.world.session_ranges.SessionRanges`) the soak applies: None."""
        return None

    def refused_faults(self) -> dict[str, str]:
        """Fault kind -> why the robot gets none: none refused."""
        return {}


class FreeWorld:
    """A free base's world: pushed as in training; ``refused`` the fault kinds it gets none of
    and why (default: no cable pulls)."""

    def __init__(self, refused: dict[str, str] | None = None):
        if refused is None:
            refused = {"cable": "a floating-base robot gets no cable pulls"}
        self._refused = dict(refused)

    def domain_pushes(self, ranges):
        """``ranges.pushes`` (:class:`~sim2real.eval.world.pushes.PushRanges`, or None)."""
        return ranges.pushes

    def refused_faults(self) -> dict[str, str]:
        """Fault kind -> why the robot gets none (a copy)."""
        return dict(self._refused)


#: The soak world's face of each robot kind, by the kind's name.
WORLD_OF_KIND: Faces = Faces("soak world")
WORLD_OF_KIND.register("arm", TetheredWorld())
WORLD_OF_KIND.register("legged", FreeWorld())
