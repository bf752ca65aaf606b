"""Run one test tier under its time budget: ``python tests/budget.py TIER SECONDS -- CMD ...``.

Runs ``CMD`` (its output passes through), then prints the tier's wall time against its
budget and, when the command wrote a JUnit XML file (``--junit FILE``), its ten slowest
tests.  Exits with the command's status, or 1 when the tier ran past 1.5 times its budget
(so the suite cannot creep back past what CI allows).  Each tier's time is appended to
``build/tiers/times.tsv``; ``python tests/budget.py --summary`` prints them.
"""

import argparse
import os
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

TIMES = Path(__file__).resolve().parent.parent / "build" / "tiers" / "times.tsv"
OVER = 1.5


def slowest(junit, n=10):
    """``(seconds, test id)`` of the ``n`` slowest test cases in a JUnit XML file."""
    cases = []
    for case in ET.parse(junit).getroot().iter("testcase"):
        cases.append((float(case.get("time", 0)), f"{case.get('classname', '')}::{case.get('name', '')}"))
    return sorted(cases, reverse=True)[:n]


def load():
    try:
        return "load %.1f" % os.getloadavg()[0]
    except (AttributeError, OSError):  # no load average on Windows
        return "load unknown"


def summary():
    if not TIMES.is_file():
        print("no tier has run yet")
        return 0
    rows = [line.split("\t") for line in TIMES.read_text().splitlines() if line]
    print("\ntier times (wall s, budget s, load at the end):")
    for tier, wall, budget, ld in rows:
        print(f"  {tier:<14} {float(wall):7.0f} s  of {float(budget):5.0f} s  {ld}")
    print(f"  {'total':<14} {sum(float(r[1]) for r in rows):7.0f} s")
    return 0


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--summary"]:
        return summary()
    if "--" not in argv:
        raise SystemExit(__doc__.splitlines()[0])
    cut = argv.index("--")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tier")
    ap.add_argument("budget", type=float, help="seconds")
    ap.add_argument("--junit", type=Path)
    a = ap.parse_args(argv[:cut])
    cmd = argv[cut + 1:]
    if a.junit is not None:
        a.junit.unlink(missing_ok=True)
    t0 = time.monotonic()
    rc = subprocess.call(cmd)
    wall = time.monotonic() - t0
    ld = load()
    print(f"\n== tier {a.tier}: {wall:.0f} s of its {a.budget:.0f} s budget ({ld}, {os.cpu_count()} cores)")
    if a.junit is not None and a.junit.is_file():
        for sec, name in slowest(a.junit):
            print(f"   {sec:7.1f} s  {name}")
    TIMES.parent.mkdir(parents=True, exist_ok=True)
    with open(TIMES, "a") as f:
        f.write(f"{a.tier}\t{wall:.1f}\t{a.budget:.0f}\t{ld}\n")
    if rc == 0 and wall > OVER * a.budget:
        print(f"== tier {a.tier} ran {wall / a.budget:.2f} times its budget (limit {OVER}): "
              "make its slowest tests cheaper or move their hard cases to the full tier")
        return 1
    return rc


if __name__ == "__main__":
    sys.exit(main())
