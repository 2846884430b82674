"""The safety guard: limits, workspace, self-collision and effort checks on every target
(guard), and the motion envelope that certifies every smoother step (envelope).
"""
