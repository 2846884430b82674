"""What a soak session throws at the robot, and training draws from too: randomized dynamics
(dynamics), sensors (sensors), floor (floor) and drift (drift), the seeded fault schedule
(fault_schedule), the ranges they are drawn from (session_ranges, overridden by a TOML file:
ranges_file) and one session's draw from its seed (session_draw).
"""
