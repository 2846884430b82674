"""Soak sessions and campaigns: hours of the runtime against a randomized, faulty MuJoCo plant.

The soak harness, by concept:

- :mod:`sim2real.eval.soak.session`: one session: its options
  (:class:`~sim2real.eval.soak.session.SessionConfig`), its folder
  (:func:`~sim2real.eval.soak.session.session_dir`), its book-keeping inside a batch (faults and the runtime's
  responses, latches, operator resets, curves, checkpoints).
- :mod:`sim2real.eval.soak.result`: a session's result document and its ``result.json``.
- :mod:`sim2real.eval.soak.faults`: the batch's fault injector, one per session on its own env.
- :mod:`sim2real.eval.soak.batch`: the batched runner, several sessions stepped in one plant and one
  runtime, with its checkpoints and divergence handling.
- :mod:`sim2real.eval.soak.batch_plant`: the batch's plant, one randomized model and sensor setting per
  session.
- :mod:`sim2real.eval.soak.checkpoint`: a session's checkpoint file (the state dicts of every stage).
- :mod:`sim2real.eval.soak.executors`: how batches are dispatched: in this process, in local processes,
  or on Ray.
- :mod:`sim2real.eval.soak.campaign`: several seeded sessions planned into batches and run
  (:func:`~sim2real.eval.soak.campaign.run_campaign`).
"""
