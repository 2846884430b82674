"""State estimation: the joints (Kalman filters, compiled kernel), a floating base (IMU and leg
kinematics), falls.
"""
