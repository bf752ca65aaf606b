"""The suite's own layout: pytest imports test files by basename (rootdir-relative, no packages), so
two files of one name clash when one process collects both (with -n, only when they land in the
same worker: a failure that comes and goes)."""

from collections import Counter
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def test_test_file_names_are_unique():
    names = Counter(p.name for p in TESTS.rglob("test_*.py"))
    assert not [n for n, c in names.items() if c > 1], sorted(p for p in TESTS.rglob("test_*.py")
                                                             if names[p.name] > 1)
