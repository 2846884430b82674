"""What a soak session throws at the robot: randomized dynamics, sensors and drift
(randomization) and the seeded fault schedule (fault_schedule).
"""
