"""Background threads of the backends and emulators: one shape for each.

- :class:`Worker`: a daemon thread running a loop until its stop event is set (the Unitree
  backend's LowCmd stream and its hold of the home pose), started and stopped any number of times.
- :class:`ServesOnThread`: an emulator that serves in the calling thread (``serve()``) or on a
  daemon thread of its own (``start()``, ``with emulator: ...``), until ``request_stop()``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import ClassVar


class Worker:
    """A daemon thread named ``name`` running ``loop(stop)`` until ``stop`` (its
    :class:`threading.Event`) is set by :meth:`stop`; ``join_timeout`` s to wait for it then."""

    def __init__(
        self, name: str, loop: Callable[[threading.Event], None], join_timeout: float = 2.0
    ):
        self.name = name
        self._loop = loop
        self._join_timeout = join_timeout
        self._event = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        """Started and not stopped since."""
        return self._thread is not None

    def start(self) -> None:
        """Start the loop on a new thread (nothing when it runs already)."""
        if self._thread is not None:
            return
        self._event.clear()
        self._thread = threading.Thread(
            target=self._loop, args=(self._event,), name=self.name, daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        """Set the stop event and wait for the loop to return (nothing when not running)."""
        if self._thread is None:
            return
        self._event.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=self._join_timeout)
        self._thread = None


class ServesOnThread:
    """Mixin of an emulator with ``serve()`` (blocking until ``self._stop``, a
    :class:`threading.Event`, is set) and ``stop()`` (idempotent; joins ``self._thread``): the
    context manager, :meth:`start` and :meth:`request_stop` around them. The emulator sets
    ``_stop`` and ``_thread = None`` in its constructor and names its thread ``THREAD_NAME``."""

    THREAD_NAME: ClassVar[str] = "emulator"
    _stop: threading.Event
    _thread: threading.Thread | None

    def serve(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        """Serve on a daemon thread (idempotent)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self.serve, name=self.THREAD_NAME, daemon=True)
            self._thread.start()

    def request_stop(self) -> None:
        """Ask :meth:`serve` to return (safe from a signal handler); :meth:`stop` also closes."""
        self._stop.set()
