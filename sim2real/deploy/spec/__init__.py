"""The policy's contract: PolicySpec (observation blocks, action, rates; JSON), its
defaults for a robot, its JSON schema, and the observation plan the tick fills.
"""
