"""LeRobot's policies beside our runtime: an exported ACT's action chunks run on the MuJoCo SO-101
through deploy-run's runtime (:mod:`~sim2real.eval.lerobot.action_chunks`, a thin wrapper), and a LeRobot
dataset written from our simulation with lerobot's own classes (:mod:`~sim2real.eval.lerobot.
dataset`). docs/lerobot.md."""
