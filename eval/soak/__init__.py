"""Soak sessions and campaigns: hours of the runtime against a randomized, faulty MuJoCo plant.

The soak harness, by concept:

- :mod:`eval.soak.session`: one session: its options (:class:`~eval.soak.session.SessionConfig`),
  its folder (:func:`~eval.soak.session.session_dir`), its book-keeping inside a batch (faults
  and the runtime's responses, latches, operator resets, curves, checkpoints).
- :mod:`eval.soak.result`: a session's result document and its ``result.json``.
- :mod:`eval.soak.faults`: the batch's fault injector, one per session on its own env.
- :mod:`eval.soak.batch`: the batched runner, several sessions stepped in one plant and one
  runtime, with its checkpoints and divergence handling.
- :mod:`eval.soak.checkpoint`: a session's checkpoint file (the state dicts of every stage).
- :mod:`eval.soak.executors`: how batches are dispatched: in this process, in local processes,
  or on Ray.
- :mod:`eval.soak.campaign`: several seeded sessions planned into batches and run
  (:func:`~eval.soak.campaign.run_campaign`).
"""
