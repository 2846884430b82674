"""The network call of a chunked policy off the servo thread (:class:`ChunkWorker`): one daemon
thread that runs the requests (:class:`ChunkRequest`) in the order they were asked, while the
servo loop goes on ticking. ONNX Runtime releases the GIL in ``InferenceSession.run``, so the
servo thread and the call share the CPU, not the interpreter.

The worker belongs to the policy stage that asks
(:class:`~sim2real.deploy.policy.lerobot_policy.LeRobotChunkPolicy` with async inference), starts
at its first request and ends at :meth:`ChunkWorker.close` (the run's end, on every exit path:
the chunk hook's close and discard).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable

import numpy as np

#: The worker thread's name (what a test looks for in ``threading.enumerate()``).
THREAD_NAME = "chunk-worker"


class ChunkRequest:
    """One network call asked: its feed (``{input name: array}``, copies taken when asked) and,
    once :attr:`done`, its chunk or the error the call raised.

    Attributes:
        done: ``threading.Event`` set when the call ended (or was dropped at close).
    """

    __slots__ = ("feed", "result", "error", "done")

    def __init__(self, feed: dict | None):
        self.feed = feed
        self.result: np.ndarray | None = None
        self.error: BaseException | None = None
        self.done = threading.Event()

    @classmethod
    def finished(cls, chunk: np.ndarray) -> ChunkRequest:
        """A request already answered with ``chunk`` (a checkpoint's pending chunk, loaded)."""
        r = cls(None)
        r.result = np.array(chunk, dtype=np.float32)
        r.done.set()
        return r

    def wait(self, timeout: float | None) -> bool:
        """Wait up to ``timeout`` s (None: until done); True when done."""
        return self.done.wait(timeout)

    def chunk(self) -> np.ndarray:
        """The call's output (call after :meth:`wait` returned True).

        Raises:
            Exception: the error the network call raised, on the asking thread.
        """
        if self.error is not None:
            raise self.error
        return self.result


class ChunkWorker:
    """A daemon thread that runs ``run(feed)`` for each :meth:`submit`, in order.

    Args:
        run: ``feed -> chunk``, the network call (``InferenceSession.run(None, feed)[0]``).
    """

    def __init__(self, run: Callable[[dict], np.ndarray]):
        self._run = run
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._closed = False

    @property
    def alive(self) -> bool:
        """Whether the thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def submit(self, feed: dict) -> ChunkRequest:
        """Ask for ``run(feed)`` on the worker thread (started at the first request)."""
        request = ChunkRequest(feed)
        if self._thread is None:
            self._closed = False
            self._thread = threading.Thread(target=self._loop, name=THREAD_NAME, daemon=True)
            self._thread.start()
        self._jobs.put(request)
        return request

    def _loop(self) -> None:
        while True:
            request = self._jobs.get()
            if request is None:
                return
            if not self._closed:
                try:
                    request.result = self._run(request.feed)
                except BaseException as exc:  # noqa: BLE001 - raised on the asking thread
                    request.error = exc
            else:
                request.error = RuntimeError("the chunk worker was closed before this call ran")
            request.feed = None
            request.done.set()

    def close(self) -> None:
        """End the thread: the call running finishes (at most one network call's time), the
        requests not started are dropped (their error says so); the thread is joined. A
        :meth:`submit` after it starts a new thread."""
        thread, self._thread = self._thread, None
        if thread is None:
            return
        self._closed = True
        self._jobs.put(None)
        thread.join()
