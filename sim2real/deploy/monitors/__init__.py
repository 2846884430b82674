"""What a run did: violations (the true state past a limit, simulation only) and
interventions (commands the guard or the smoother changed).
"""
