"""Soak batches on Ray, on nodes that share no disk with the driver.

:func:`run_ray` runs each batch as one Ray task of one CPU (:func:`batch_task`), a generator task
(Ray's streaming generators, ``ray.wait`` over them): the campaign's inputs travel to it through
Ray's object store (``ray.put`` once, :func:`sim2real.eval.soak.transport.pack_inputs`), with the
sessions' folders when the campaign resumes; the worker runs the batch
(:func:`sim2real.eval.soak.executors.run_sessions`) in its own temporary folder and yields what
changed in the sessions' folders after every checkpoint and progress report, then the results.
The driver writes each change into its campaign folder as a local run does
(:func:`sim2real.eval.soak.transport.apply_changes`), so the progress display, ``--resume`` and the
report read them there; a driver killed mid-campaign keeps the checkpoints that reached it, and
``--resume`` ships them back out. A task is not retried by Ray (``max_retries=0``): a lost node is
an error naming the batch, and ``--resume`` continues it from its last checkpoint.

Errors: a worker's own error (bad input, a checkpoint that does not fit: ``ValueError``,
``OSError``) is raised on the driver as itself, one line, not Ray's traceback; any other failure of
a task is a :class:`RayExecutorError` naming the batch's sessions.
"""

from __future__ import annotations

import os
import queue
import shutil
import tempfile
import threading
from pathlib import Path

from sim2real.eval.soak.executors import default_workers, run_sessions
from sim2real.eval.soak.session import SessionConfig
from sim2real.eval.soak.transport import (
    FolderSync,
    Inputs,
    Relabel,
    apply_changes,
    materialise,
    pack_sessions,
    unpack_sessions,
    worker_config,
)
from sim2real.robots.errors import Sim2RealError


class RayExecutorError(Sim2RealError, OSError):
    """A Ray task of a campaign failed other than by our own error (its node lost, its worker
    killed, an unexpected exception); the message names the batch's sessions."""


def batch_task(
    inputs: Inputs,
    batch: list[SessionConfig],
    out: str,
    resume: bool,
    sessions: bytes | None,
    recorders: tuple = (),
):
    """Run one batch on a worker (the body of :func:`run_ray`'s generator task).

    Args:
        inputs: The campaign's inputs (:func:`sim2real.eval.soak.transport.pack_inputs`).
        batch: The sessions' options on the driver.
        out: The driver's campaign folder (absolute); the worker's is the same path under its own
            temporary folder, removed at the end.
        resume: Continue from the sessions' checkpoints.
        sessions: The sessions' folders (:func:`sim2real.eval.soak.transport.pack_sessions`) or None.
        recorders: As :func:`sim2real.eval.soak.executors.run_sessions`'s.

    Yields:
        ``("files", changes)`` (:meth:`sim2real.eval.soak.transport.FolderSync.changes`) after every
        checkpoint and progress report, then ``("results", results)``: one result per session, in
        order, with the driver's paths.

    Raises:
        Whatever :func:`sim2real.eval.soak.executors.run_sessions` raises.
    """
    root = Path(tempfile.mkdtemp(prefix="sim2real-soak-")).resolve()
    here = os.getcwd()
    try:
        work = materialise(inputs, root)
        relabel = Relabel(batch, inputs, root)
        configs = [worker_config(c, inputs, root) for c in batch]
        worker_out = root / out.lstrip("/")
        unpack_sessions(sessions, worker_out, relabel)
        sync = FolderSync(worker_out, [c.seed for c in batch], relabel)
        messages: queue.Queue = queue.Queue()

        def ship() -> None:
            messages.put(("files", sync.changes()))

        class Ship:
            """A recorder that ships every checkpoint as soon as it is written."""

            def __init__(self, _batch):
                pass

            def supervise(self, _rt) -> None:
                pass

            def checkpointed(self) -> None:
                ship()

            def finish(self) -> None:
                pass

        def run() -> None:
            try:
                results = run_sessions(configs, str(worker_out), resume, ship, (*recorders, Ship))
                ship()
                messages.put(("results", relabel.to_driver(results)))
            except BaseException as exc:  # noqa: BLE001 - raised again by the task below
                messages.put(("error", exc))

        os.chdir(work)  # a relative option names the file it names on the driver
        thread = threading.Thread(target=run, name="soak-batch", daemon=True)
        thread.start()
        while True:
            kind, payload = messages.get()
            if kind == "error":
                raise relabel.error(payload)
            yield kind, payload
            if kind == "results":
                break
        thread.join()
    finally:
        os.chdir(here)
        shutil.rmtree(root, ignore_errors=True)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"


def run_ray(
    batches: list[list[SessionConfig]],
    out: Path,
    resume: bool,
    address: str | None,
    workers: int | None,
    bar,
    recorders=(),
    inputs: Inputs | None = None,
) -> list[list[dict]]:
    """Run each batch as a :func:`batch_task` Ray task (one CPU each); ``bar.update()`` is called
    while waiting.

    Ray is initialized here unless it already is in this process: on the cluster at ``address``,
    or as a local instance of ``workers`` CPUs (default: one per core); it is shut down again at
    the end if it was started here.

    Args:
        inputs: The campaign's inputs (:func:`sim2real.eval.soak.transport.pack_inputs`).

    Returns:
        The results of each batch, in the order of ``batches``.

    Raises:
        ValueError, OSError: a worker's own error, as raised there (one line).
        RayExecutorError: any other failure of a task.
    """
    import ray
    from ray.exceptions import RayError, RayTaskError

    if inputs is None:
        raise ValueError("run_ray: inputs: expected the campaign's packed inputs, got None")
    started = False
    if not ray.is_initialized():
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(
                num_cpus=workers or default_workers(), include_dashboard=False, log_to_driver=False
            )
        started = True
    out = Path(out)
    pending: dict[int, object] = {}
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(batch_task)
        shared = ray.put(inputs)
        absolute = str(out.resolve())
        for i, b in enumerate(batches):
            sessions = pack_sessions(out, [c.seed for c in b]) if resume else None
            pending[i] = task.remote(shared, b, absolute, resume, sessions, recorders)
        results: list = [None] * len(batches)
        while pending:
            ready, _ = ray.wait(list(pending.values()), num_returns=len(pending), timeout=0.5)
            ready_ids = {id(g) for g in ready}
            for i in [i for i, g in pending.items() if id(g) in ready_ids]:
                ids = [c.id for c in batches[i]]
                try:
                    kind, payload = ray.get(next(pending[i]))
                except StopIteration:
                    raise RayExecutorError(
                        f"ray: the task of sessions {ids} ended without their results"
                    ) from None
                except RayTaskError as exc:
                    cause = getattr(exc, "cause", None)
                    if isinstance(cause, (ValueError, OSError)):
                        raise cause.with_traceback(None) from None
                    raise RayExecutorError(
                        f"ray: the task of sessions {ids} failed: {_first_line(cause or exc)}"
                    ) from None
                except RayError as exc:
                    raise RayExecutorError(
                        f"ray: the task of sessions {ids} was lost ({_first_line(exc)}); the "
                        f"checkpoints that reached {out} are kept: run again with --resume"
                    ) from None
                if kind == "files":
                    apply_changes(out, payload)
                else:
                    results[i] = payload
                    del pending[i]
            bar.update()
        return results
    finally:
        for gen in pending.values():
            ray.cancel(gen)
        if started:
            ray.shutdown()
