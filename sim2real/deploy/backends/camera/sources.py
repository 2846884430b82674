"""The cameras of a policy that reads several (:class:`CameraSources`): one source per camera name
(a plant's camera, :class:`sim2real.deploy.backends.sim.plant_camera.PlantCamera`, or a hardware
driver of ``--camera-source``), made the backend's ``camera_source`` where a policy has more than
one image block. The runtime's camera stage (:func:`sim2real.deploy.runtime.camera.camera_stage`)
feeds each camera's input from the source of its name; the group carries what the run does to all
of them: their state in the runtime's state dict (``camera_source/<camera>/...``), the task
scene's goal, closing them, their report lines."""

from __future__ import annotations

from sim2real.deploy.core.stateful import load_named


class CameraSources:
    """Sources by camera name, in the spec's order of its image blocks.

    Args:
        sources: ``{camera name: source}``; each source has ``fill(frame)`` and ``summary()``,
            a plant camera also ``state_dict``, ``recent`` and ``show_goal``.

    Attributes:
        sources: The dict given (its order the image blocks').
    """

    def __init__(self, sources: dict):
        self.sources = dict(sources)

    def state_dict(self, env: int | None = None) -> dict:
        """Each source's ``state_dict`` that has one, under ``<camera>/``."""
        return {
            f"{name}/{k}": v
            for name, src in self.sources.items()
            if hasattr(src, "state_dict")
            for k, v in src.state_dict(env).items()
        }

    def load_state_dict(self, state, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`.

        Raises:
            StateDictError: a source's field missing or of another shape (nothing written: the
                sources loaded before it are put back)."""
        parts = [(n, s) for n, s in self.sources.items() if hasattr(s, "load_state_dict")]
        load_named(parts, state, env)

    def show_goal(self, goal) -> None:
        """Every source's task scene shows ``goal`` (a plant camera's ``show_goal``)."""
        for src in self.sources.values():
            show = getattr(src, "show_goal", None)
            if show is not None:
                show(goal)

    def close(self, hardware_only: bool = False) -> None:
        """Close the sources (with ``hardware_only``: the drivers only, whose ``feed`` a
        thread fills; a plant's camera closes with the plant)."""
        for src in self.sources.values():
            close = getattr(src, "close", None)
            if close is not None and (hasattr(src, "feed") or not hardware_only):
                close()
