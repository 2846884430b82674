"""deploy-run and policy-export: the parser, the run, its summary; the adversarial acceptance
run (``python -m sim2real.deploy.cli.deploy_run.acceptance``).
"""
