"""``python -m sim2real.bench ...``: the benchmarks (``python -m bench``, ``make bench``) from any
folder, for a checkout installed in editable mode (``make install``, ``pip install -e .``).

The benchmarks live in the checkout's ``bench/`` beside their baselines and results
(``bench/baseline/``, ``bench/results.json``, ``bench/history.jsonl``), not in the installed
package: ``pip install .`` puts one top-level package, ``sim2real`` (``tests/test_public_api.py``).
This module finds the checkout the package was installed from (the folder holding
``sim2real/``, when it also holds ``bench/__main__.py``) and runs its ``bench`` there, with the
arguments given; without such a checkout (a wheel's install) it says so in one line and exits 2.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

#: Exit code when no checkout's ``bench/`` is found (argparse's for bad usage).
EXIT_NO_CHECKOUT = 2


def checkout() -> Path | None:
    """The source checkout the package was installed from (holding ``bench/__main__.py``), or
    None."""
    root = Path(__file__).resolve().parent.parent
    return root if (root / "bench" / "__main__.py").is_file() else None


def main(argv: list[str] | None = None) -> int:
    """Run the checkout's ``python -m bench`` with ``argv`` (default: this process's); returns
    its exit code (0 when it returns normally), or :data:`EXIT_NO_CHECKOUT`."""
    root = checkout()
    if root is None:
        print(
            "sim2real.bench: no source checkout beside the installed package (the benchmarks live "
            "in a checkout's bench/: clone it and pip install -e it, or run python -m bench there)",
            file=sys.stderr,
        )
        return EXIT_NO_CHECKOUT
    args = sys.argv[1:] if argv is None else list(argv)
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    try:
        return int(importlib.import_module("bench.__main__").main(args) or 0)
    except SystemExit as exc:  # argparse's --help and usage errors
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)


if __name__ == "__main__":
    sys.exit(main())
