"""Sim-to-sim: the same policy soaked on two physics engines, and what differs.

A soak (:mod:`sim2real.eval.soak`) judges a policy against one simulated plant. Part of what it measures
is the policy and part is the physics engine's model of the robot: contacts, friction at the
feet and at the joint stops, the integrator, the solver's compliance. Running the same campaign
(robot, policy, seeds, hours, options) with another engine (``soak-test --engine``) keeps the
policy, the randomized dynamics, the goals or velocity commands and the faults the same, so that
a gap between the two reports is the engines'. A policy whose figures agree on both engines is
less likely to rely on one engine's modelling quirks, and a step closer to the real robot; one
whose figures differ shows where: falls on one engine only, goals or tracking lost, hotter
motors, violations or safe stops that appear on one engine only.

- :mod:`sim2real.eval.sim2sim.reports`: reads and checks each engine's ``report.json`` (errors name the
  file, the field and the value expected) and extracts the figures compared.
- :mod:`sim2real.eval.sim2sim.compare`: :func:`~sim2real.eval.sim2sim.compare.compare` matches the reports'
  sessions by seed and gives each figure's value per engine, its gap and its engine-dependent
  flag (the thresholds are module constants with their reasons), and the verdict.
- :mod:`sim2real.eval.sim2sim.write`: ``sim2sim.json``, ``sim2sim.md`` (tables) and ``sim2sim.png`` (bar
  chart), written atomically.
- :mod:`sim2real.eval.sim2sim.cli`: the ``sim2sim`` command: runs ``soak-test`` once per engine into
  ``OUT/<engine>/``, then compares (exit 0 same, 3 engine-dependent, 2 bad input).
"""
