"""Write a benchmark's table into docs/benchmarks.md, each benchmark in its own section.

``write_section("contour", markdown)`` replaces the text between
``<!-- BEGIN contour -->`` and ``<!-- END contour -->`` (appending the section
the first time), stamped with the date, the machine and its load when the section
is written (the 1/5/15-minute load averages), atomically and under a
file lock so that benchmarks may run side by side.  A quick run (``--quick`` on
the command line, the smoke test of ``make test``) prints its section and
leaves docs/benchmarks.md alone: its numbers are not the benchmark's.
"""

import datetime
import os
import platform
import re
import sys
from pathlib import Path

from nephele.core.files import atomic_write, locked

DOC = Path(__file__).resolve().parent.parent / "docs" / "benchmarks.md"
HEADER = ("# Benchmarks\n\nWritten by the scripts in `benchmarks/` (`make bench`). Each section says when and where "
          "it ran.\n")


def machine():
    """One line describing this machine: CPU model, cores, memory, Python, numpy."""
    import numpy

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    mem = ""
    try:
        with open("/proc/meminfo") as f:
            kb = int(f.readline().split()[1])
            mem = f", {kb / 2**20:.0f} GiB"
    except (OSError, ValueError, IndexError):
        pass
    return f"{cpu}, {os.cpu_count()} cores{mem}, Python {platform.python_version()}, numpy {numpy.__version__}"


def load():
    """The machine's load averages now, e.g. ``"load 1.52 / 1.31 / 0.98 (1/5/15 min)"``."""
    try:
        one, five, fifteen = os.getloadavg()
    except OSError:  # not available on this platform
        return "load not available"
    return f"load {one:.2f} / {five:.2f} / {fifteen:.2f} (1/5/15 min)"


def md_table(header, rows):
    """A markdown table from a header list and rows of values (floats get 4 significant digits)."""

    def fmt(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v) for v in r) + " |" for r in rows]
    return "\n".join(lines)


def quick():
    """True for a quick (smoke) run: ``--quick`` on the command line."""
    return "--quick" in sys.argv[1:]


def write_section(name, body, title=None, doc=DOC):
    """Put ``body`` (markdown) into section ``name`` of docs/benchmarks.md (only print it in a quick run)."""
    stamp = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
    text = (
        f"<!-- BEGIN {name} -->\n## {title or name}\n\n"
        f"_Run {stamp} on {machine()}; {load()} at writing._\n\n{body.strip()}\n<!-- END {name} -->"
    )
    if quick():
        print(text)
        print(f"(quick run: {Path(doc).name} not written)")
        return
    doc = Path(doc)
    doc.parent.mkdir(parents=True, exist_ok=True)
    with locked(doc.with_suffix(".lock")):
        old = doc.read_text() if doc.exists() else HEADER
        pattern = re.compile(rf"<!-- BEGIN {re.escape(name)} -->.*?<!-- END {re.escape(name)} -->", re.S)
        new = pattern.sub(lambda m: text, old) if pattern.search(old) else old.rstrip() + "\n\n" + text + "\n"
        with atomic_write(doc) as tmp:
            tmp.write_text(new)
    print(text)
