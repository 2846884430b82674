"""robot-import: a URDF or an MJCF (fixed base or legged) into sim2real/robots/<name>/ (MJCF plus
robot.toml); cli is the command, source the checked description every format becomes, model
the shared conversion.
"""
