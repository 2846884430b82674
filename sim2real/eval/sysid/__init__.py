"""Identification of a robot's motors from its own log (``sysid``): the commands a run sent
replayed through the plant (:mod:`~sim2real.eval.sysid.replay`), the plant's motors fitted until the
replay reads what the robot read (:mod:`~sim2real.eval.sysid.fit`), and the gap between the log and the
plant with the described motors and with the fitted ones (:mod:`~sim2real.eval.sysid.gap`); the command
line is :mod:`~sim2real.eval.sysid.cli`.
"""
