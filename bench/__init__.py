"""Benchmarks (`make bench`): speed is measured here, never by timed unit tests.

``python -m bench`` (:mod:`bench.__main__`: usage, options; the targets :mod:`bench.targets`) measures
the runtime against a bare sim2sim loop (unitree_rl_gym's ``deploy_mujoco.py``: torch eager, PD
torques at the physics rate) on the same robot and policy in the same run, writes
``bench/results.json`` atomically (schema ``sim2real-deploy/bench/1``; its layout and the targets
in docs/speed.md) and prints a plain-text table ending with the targets, PASS or FAIL.

The policy of every item but ``inference`` (:mod:`bench.common`): a deterministic
:class:`sim2real.deploy.policy.mlp_checkpoint.MLPActor` (hidden 64, 64, ELU, weights from
``torch.manual_seed(0)``) over the robot's default PolicySpec, its weights tamed so that it holds
the arm near home and moves it a little with every goal (:func:`bench.common.tame_actor`), exported
with the parity gate; goals from :class:`sim2real.deploy.tasks.goals.GoalScheduler` as in ``deploy-run``.
Every latency goes through :class:`sim2real.deploy.core.latency.LatencyHistogram`.

Items, one module each (its docstring says how it measures):

- ``plant`` (:mod:`bench.plant`): MuJoCo alone and the whole ``SimBackend``, per control tick;
- ``inference`` (:mod:`bench.policy_inference`): export time and batch-1 inference;
- ``tick`` (:mod:`bench.tick`): per-stage cost of the full runtime and of the bare loop;
- ``session`` (:mod:`bench.session`): ``deploy-run`` extrapolated to an 8-hour session;
- ``campaign`` (:mod:`bench.campaign`): simulated seconds per wall second on every core, and the
  share of physics-only stepping kept;
- ``wallclock`` (:mod:`bench.session`): ``deploy-run --realtime`` per wait mode and scheduler;
- ``bus`` (:mod:`bench.bus`): a servo-bus tick through the vendor SDK against the emulator;
- ``camera`` (:mod:`bench.camera_cost`): a depth camera's render per frame and its noise model's
  error at 1 m and 2 m;
- ``profile`` (:mod:`bench.profiling`, only with ``--only profile``): cProfile of the runtime.
"""
