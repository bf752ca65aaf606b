"""Long fuzz runs of every reader, outside CI: ``make fuzz N=100000`` (``python tests/fuzz/run.py --cases N``).

Prints the count of each outcome per reader; every finding (an error other
than ``DataError``, a case over 10 s or 2 GiB, a crash) is saved under
``--out`` with the ops that made it, and makes the exit status 1.
"""

import argparse
import collections
import json
import random
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fuzzlib import BAD, ROOT, Runner, build_seeds, cases, describe  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=None, help="random seed (default: from the clock, printed)")
    ap.add_argument("--out", default="build/fuzz", help="folder for the findings")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes at once (default 1)")
    ap.add_argument("--only", action="append",
                    help="fuzz only these readers (netcdf, grib, zarr, grads, relief, pqr, vtu)")
    ap.add_argument("--data", action="append", default=None,
                    help="seed folders (default: tests/data and ../shared/data)")
    args = ap.parse_args(argv)
    seed = args.seed if args.seed is not None else int(time.time())
    rng = random.Random(seed)
    dirs = args.data or [d for d in (ROOT / "tests" / "data", ROOT.parent / "shared" / "data") if d.is_dir()]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    counts = collections.defaultdict(collections.Counter)
    findings = 0
    t0 = time.time()
    with tempfile.TemporaryDirectory() as work:
        seeds = [s for s in build_seeds(dirs, work) if not args.only or s.target in args.only]
        print(f"fuzz: seed {seed}, {len(seeds)} seed files ({', '.join(sorted({s.target for s in seeds}))}), "
              f"{args.cases} cases, {args.jobs} worker(s)", flush=True)
        stream = zip(range(args.cases), cases(seeds, rng))
        lock = threading.Lock()

        def work_loop():
            nonlocal findings
            runner = Runner()
            try:
                while True:
                    with lock:
                        item = next(stream, None)
                    if item is None:
                        return
                    i, (s, mutated, ops) = item
                    res = runner.run(s, mutated, ops)
                    with lock:
                        counts[s.target][res["status"]] += 1
                        done = sum(sum(c.values()) for c in counts.values())
                        if res["status"] in BAD:
                            findings += 1
                            print(describe(s, mutated, ops, res), flush=True)
                            (out / f"finding-{seed}-{i}.json").write_text(json.dumps(
                                {"target": s.target, "seed": s.name, "mutated": mutated, "ops": ops, "result": res},
                                indent=1))
                        if done % 1000 == 0:
                            print(f"fuzz: {done} cases, {findings} findings, {time.time() - t0:.0f} s", flush=True)
            finally:
                runner.close()

        threads = [threading.Thread(target=work_loop) for _ in range(args.jobs)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    total = sum(sum(c.values()) for c in counts.values())
    for target in sorted(counts):
        c = counts[target]
        print(f"  {target:7s} {sum(c.values()):7d} cases: " + ", ".join(f"{k} {v}" for k, v in sorted(c.items())))
    print(f"fuzz: {total} cases in {time.time() - t0:.0f} s, {findings} findings (seed {seed})")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
