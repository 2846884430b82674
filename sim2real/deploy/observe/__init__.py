"""Watching a run: telemetry (MCAP), Foxglove schemas, video, the MuJoCo viewer, the joint
printer.
"""
