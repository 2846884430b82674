"""Sum a ``SIM2REAL_TEST_CPU`` file (tests/conftest.py) by test and by file.

Usage: ``python tests/cpu_table.py CPU_FILE [--top N] [--files]``: the total CPU seconds, each
worker's collection CPU and last end time, then the N tests (setup + call + teardown) or the
files of most CPU.
"""

from __future__ import annotations

import argparse
import collections


def read(path: str):
    """``(tests, collections, ends)``: {nodeid: cpu s}, {worker: collection cpu s},
    {worker: last end time}."""
    tests: dict[str, float] = collections.defaultdict(float)
    colls: dict[str, float] = {}
    ends: dict[str, float] = {}
    with open(path, encoding="utf-8") as f:
        for line in f:
            worker, nodeid, _phase, cpu, _wall, end = line.rstrip("\n").split("\t")
            ends[worker] = max(ends.get(worker, 0.0), float(end))
            if nodeid == "<collection>":
                colls[worker] = float(cpu)
            else:
                tests[nodeid.split("@")[0]] += float(cpu)
    return tests, colls, ends


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("path")
    p.add_argument("--top", type=int, default=40)
    p.add_argument("--files", action="store_true")
    a = p.parse_args()
    tests, colls, ends = read(a.path)
    print(f"tests {len(tests)}, test CPU {sum(tests.values()):.1f} s")
    for w in sorted(colls):
        print(f"  {w}: collection {colls[w]:.1f} s, last end {ends[w]:.0f}")
    rows = tests
    if a.files:
        rows = collections.defaultdict(float)
        for nodeid, cpu in tests.items():
            rows[nodeid.split("::")[0]] += cpu
    for name, cpu in sorted(rows.items(), key=lambda kv: -kv[1])[: a.top]:
        print(f"{cpu:8.2f}  {name}")


if __name__ == "__main__":
    main()
