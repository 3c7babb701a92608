"""Command-line start-up benchmark (issue #20): wall time of the commands that only read.

Each command runs as a fresh process (``python -m amslam ...``, the interpreter running this
script), best of ``--repeats`` runs, the commands taking turns so that a burst of load hits them
all alike. The references, measured in the same run: ``python -c pass`` (the interpreter's own
start) and ``python -c "import numpy"`` (the one library every command needs); the ratios to them
are the steadier figures on a shared machine, and so is the CPU time (user + system) of the
process, which waiting for a busy core does not inflate. The load average before and after is
printed.

Bytecode caches are written and used as in a normal install (``PYTHONDONTWRITEBYTECODE`` is
dropped from the children's environment), and one unmeasured run of each command warms them and
the file cache first.

``--importtime N`` also prints, for ``validate demo``, the N imports that took longest (``python
-X importtime``: the modules amslam and its entry points import directly, cumulative times).

Run: ``.venv/bin/python benchmarks/cli.py [--repeats 5] [--importtime 10]``.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import time

REFERENCES = {
    "python -c pass": ["-c", "pass"],
    'python -c "import numpy"': ["-c", "import numpy"],
}
COMMANDS = {
    "amslam --help": ["-m", "amslam", "--help"],
    "amslam plugins": ["-m", "amslam", "plugins"],
    "amslam validate demo": ["-m", "amslam", "validate", "demo"],
    "amslam tree demo": ["-m", "amslam", "tree", "demo"],
    "amslam missions": ["-m", "amslam", "missions"],
}


def child_environment() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def _children_cpu() -> float:
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    return used.ru_utime + used.ru_stime


def timed(args: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of one run of ``python ARGS``."""
    cpu, start = _children_cpu(), time.perf_counter()
    done = subprocess.run([sys.executable, *args], env=env, capture_output=True, check=False)
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(args)} exited {done.returncode}: {done.stderr.decode()[-500:]}")
    return elapsed, _children_cpu() - cpu


def best_times(
    runs: dict[str, list[str]], repeats: int, env: dict[str, str]
) -> dict[str, tuple[float, float]]:
    """The best wall time and the best CPU time of each run (not necessarily of the same run)."""
    for args in runs.values():  # warm the bytecode and file caches
        timed(args, env)
    best = dict.fromkeys(runs, (float("inf"), float("inf")))
    for _ in range(repeats):
        for name, args in runs.items():
            wall, cpu = timed(args, env)
            best[name] = (min(best[name][0], wall), min(best[name][1], cpu))
    return best


def importtime_top(args: list[str], count: int, env: dict[str, str]) -> list[tuple[float, str]]:
    """The ``count`` direct imports (of ``-m amslam``, amslam's entry points and what the command
    imports) with the longest cumulative times, in ms."""
    done = subprocess.run(
        [sys.executable, "-X", "importtime", *args], env=env, capture_output=True, text=True, check=True
    )
    rows = []
    for line in done.stderr.splitlines():
        found = re.match(r"import time:\s+\d+ \|\s+(\d+) \| (\S.*)", line)  # one space: a direct import
        if found:
            rows.append((int(found[1]) / 1000, found[2].strip()))
    return sorted(rows, reverse=True)[:count]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="runs per command, the best is kept")
    parser.add_argument("--importtime", type=int, default=0, metavar="N", help="top N imports of validate")
    args = parser.parse_args()
    env = child_environment()
    load_before = os.getloadavg()
    best = best_times({**REFERENCES, **COMMANDS}, args.repeats, env)
    load_after = os.getloadavg()
    bare, numpy = best["python -c pass"][0], best['python -c "import numpy"'][0]
    print(f"Python {sys.version.split()[0]} ({sys.executable}), best of {args.repeats}")
    cpus = os.cpu_count()
    print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} (1 min); {cpus} CPUs")
    print()
    print("| command | wall s | × python -c pass | × import numpy | CPU s |")
    print("|---|---:|---:|---:|---:|")
    for name, (wall, cpu) in best.items():
        print(f"| `{name}` | {wall:.3f} | {wall / bare:.1f} | {wall / numpy:.2f} | {cpu:.3f} |")
    if args.importtime:
        print()
        print(f"`python -X importtime -m amslam validate demo`: the {args.importtime} longest direct imports")
        print()
        print("| module | cumulative ms |")
        print("|---|---:|")
        for ms, name in importtime_top(COMMANDS["amslam validate demo"], args.importtime, env):
            print(f"| {name} | {ms:.1f} |")


if __name__ == "__main__":
    main()
