"""Identification of a robot's motors from its own log (``sysid``): the commands a run sent
replayed through the plant (:mod:`~eval.sysid.replay`), the plant's motors fitted until the
replay reads what the robot read (:mod:`~eval.sysid.fit`), and the gap between the log and the
plant with the described motors and with the fitted ones (:mod:`~eval.sysid.gap`); the command
line is :mod:`~eval.sysid.cli`.
"""
