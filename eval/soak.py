"""Soak sessions and campaigns: hours of the runtime against a randomized, faulty MuJoCo plant.

The soak harness, by concept (this module re-exports their public names, so that
``from eval.soak import ...`` keeps working):

- :mod:`eval.session`: one session: its options (:class:`SessionConfig`), its folder
  (:func:`session_dir`), its book-keeping inside a batch (faults and the runtime's responses,
  latches, operator resets, curves, checkpoints).
- :mod:`eval.session_result`: a session's result document and its ``result.json``
  (:func:`read_result`).
- :mod:`eval.session_faults`: the batch's fault injector, one per session on its own env
  (:class:`SessionFaults`).
- :mod:`eval.batch`: the batched runner, several sessions stepped in one plant and one runtime
  (:class:`SessionBatch`), with its checkpoints and divergence handling.
- :mod:`eval.executors`: how batches are dispatched: in this process (:func:`run_sessions`), in
  local processes, or on Ray.
- :mod:`eval.campaign`: several seeded sessions planned into batches (:func:`plan_batches`) and
  run (:func:`run_campaign`).
"""

from __future__ import annotations

from eval.batch import (
    DRIFT_PERIOD,
    PROGRESS_PERIOD,
    STATS,
    SUPERVISE_PERIOD,
    BatchDiverged,
    SessionBatch,
)
from eval.campaign import plan_batches, run_campaign
from eval.executors import default_workers, run_sessions
from eval.session import (
    ARM_LEAD,
    RESPONSES,
    SESSIONS_DIR,
    SessionConfig,
    SessionError,
    session_dir,
)
from eval.session_faults import SessionFaults
from eval.session_result import VIOLATION_SOURCE, read_result

__all__ = [
    "ARM_LEAD",
    "DRIFT_PERIOD",
    "PROGRESS_PERIOD",
    "RESPONSES",
    "SESSIONS_DIR",
    "STATS",
    "SUPERVISE_PERIOD",
    "VIOLATION_SOURCE",
    "BatchDiverged",
    "SessionBatch",
    "SessionConfig",
    "SessionError",
    "SessionFaults",
    "default_workers",
    "plan_batches",
    "read_result",
    "run_campaign",
    "run_sessions",
    "session_dir",
]
