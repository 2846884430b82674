"""The MuJoCo plant behind the Backend interface: the plant, its drives, its joint and base sensor
models, its state, fault injection, and the interactive demo.
"""
