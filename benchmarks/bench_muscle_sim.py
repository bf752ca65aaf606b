"""Cross-bridge simulation: time-step error against an exact anchor, and seconds per film frame.

Part 1: heads on their hinge springs (no collisions), Euler-Maruyama at
several ``k dt / drag``: the sampled rotation variance against kT/k, beside
the anchor measured in the same run, the exact Ornstein-Uhlenbeck update
(``x -> x e^{-a} + sqrt(kT/k (1 - e^{-2a})) xi``, exact for any step), whose
error is only the sampling noise.  Part 2: the full 214.5 nm cell (270 heads,
468 actin subunits, two hinges per head, elastic collisions, cycle, sliding): seconds per film frame at
the default step and at half of it, and the film's 240 frames extrapolated
against the 60 s goal.

Usage: ``python benchmarks/bench_muscle_sim.py [--quick]``.
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import md_table, write_section  # noqa: E402

from nephele.core.muscle import brownian as br  # noqa: E402
from nephele.core.muscle import lattice as lat  # noqa: E402

KT = br.KT_300


def hinge(a, n, samples, exact=False, seed=0):
    """Sampled variance / (kT/k) of rotation-vector components, seconds per step (n heads)."""
    rng = np.random.default_rng(seed)
    drag = br.Params().head_drag
    k = 100 * KT
    dt = a * drag / k
    req = br.rotation_matrix(rng.normal(0, 1, (n, 3)))
    rot = req.copy()
    x = np.zeros((n, 3))
    every = max(1, int(round(2 / a)))  # two relaxation times between samples
    burn = 5 * every
    out = []
    t0 = time.perf_counter()
    steps = burn + samples * every
    for s in range(steps):
        w = br.rotation_vector(rot @ req.transpose(0, 2, 1))
        if exact:
            new = w * np.exp(-a) + np.sqrt(KT / k * (1 - np.exp(-2 * a))) * rng.standard_normal(w.shape)
            rot = br.rotation_matrix(new) @ req
        else:
            x, rot = br.brownian_step(x, rot, dt, 1.0, drag, rng, torque=-k * w)
        if s >= burn and (s - burn) % every == 0:
            out.append(br.rotation_vector(rot @ req.transpose(0, 2, 1)))
    sec = (time.perf_counter() - t0) / steps
    return float(np.var(np.concatenate(out)) / (KT / k)), sec


def part1(quick):
    n, samples = (2000, 20) if quick else (4000, 40)
    rows = []
    ratio, sec = hinge(0.05, n, samples, exact=True)
    noise = np.sqrt(2 / (3 * n * samples))
    rows.append(("exact OU (anchor)", 0.05, "-", f"{100 * (ratio - 1):+.2f}", f"{1e3 * sec:.2f}"))
    for a in (0.01, 0.05, 0.1, 0.2):
        ratio, sec = hinge(a, n, samples)
        rows.append(("Euler-Maruyama", a, f"{100 * (1 / (1 - a / 2) - 1):+.2f}", f"{100 * (ratio - 1):+.2f}",
                     f"{1e3 * sec:.2f}"))
    return rows, noise


def part2(quick):
    frames = 6 if quick else 24
    rows = []
    for dt in (0.01, 0.005):
        sim = br.CrossBridges(lat.unit_cell(), br.Params(dt=dt), seed=0)
        steps = frames * sim.p.steps_per_frame
        bounces = refused = 0
        fr = [sim.frame()]
        t0 = time.perf_counter()
        for _ in range(frames):
            for _ in range(sim.p.steps_per_frame):
                sim.step()
                bounces += sim.collisions
                refused += sim.rejected
            fr.append(sim.frame())
        sec = (time.perf_counter() - t0) / frames
        bound = np.mean([(f.sites >= 0).sum() for f in fr[1:]])
        rows.append((dt, sim.p.steps_per_frame, f"{sec:.3f}", f"{240 * sec:.0f}", f"{bound:.0f}",
                     f"{fr[-1].slide.mean():+.1f}", f"{bounces / steps:.1f}", f"{refused / steps:.2f}"))
    return rows, frames


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer samples and frames (smoke run)")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    r1, noise = part1(args.quick)
    r2, frames = part2(args.quick)
    load1 = os.getloadavg()[0]
    body = (
        f"Machine shared with other jobs (load average {load0:.1f} at the start, {load1:.1f} at the end, "
        f"{os.cpu_count()} cores): timings are upper bounds.\n\n"
        "Heads on hinge springs of k = 100 kT (no collisions): the variance of the rotation vector's components "
        f"against kT/k; sampling noise about {100 * noise:.2f} % (1 sigma). The predicted Euler-Maruyama bias is "
        "1/(1 - a/2) - 1 for a = k dt / drag; `check_step` refuses a > 0.2.\n\n"
        + md_table(["integrator", "a = k dt / drag", "predicted %", "measured %", "ms per step"], r1)
        + f"\n\nFull 214.5 nm cell (270 heads with lever and elbow hinges, elastic collisions, cycle, sliding), "
        f"{frames} film frames of 0.1 us; bounces are elastic head collisions resolved, refused the moves a bounce "
        "could not clear (kept in place):\n\n"
        + md_table(["dt (us)", "steps per frame", "s per frame", "240 frames (s, goal <= 60)", "heads bound",
                    "mean slide (nm)", "bounces per step", "refused per step"], r2)
    )
    write_section("muscle_sim", body, title="Muscle cross-bridge simulation")


if __name__ == "__main__":
    main()
