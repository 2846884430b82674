"""``python -m deploy.export``: the ``policy-export`` command (:func:`deploy.export.cli.main`)."""

from deploy.export.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
