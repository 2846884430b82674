"""What the robot is asked to do: reach goals (an arm) and velocity commands (a legged robot)."""
