#!/usr/bin/env python
"""False alarms and power of the depth effects on simulated registration residuals.

Priors err in size independently (log scale ~ N(0, spread)); a depth scale moves all of
them together. For 3-8 objects and spreads of 1.5-4 %, this draws the per-object scales,
ranks the depth effects (depth_scale, depth_offset, depth_bias) and counts how often one
is supported, with three noise rules: the median absolute deviation (the rule before the
noise bar), the sample deviation, and the sample deviation with the noise bar (bootstrap
over objects and the F quantile, ``r2s.diagnose.stats.noise``). With ``--scale`` the
draws carry a depth scale and the count is the power.

  python scripts/diagnose_noise_bar.py --draws 20            # false alarms
  python scripts/diagnose_noise_bar.py --draws 20 --scale 1.04
  python scripts/diagnose_noise_bar.py --draws 10 --prior 0.025,20 --rules bar

``--prior SIGMA,DOF`` is the prior spread pooled into the sample deviation and how many
objects' worth it counts (the stage's ``prior_scale_sigma`` and ``prior_scale_dof``;
default: the former 2 %, 4).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from r2s.diagnose.data import RegistrationData, Residuals, ScaleObs  # noqa: E402
from r2s.diagnose.effects import all_effects  # noqa: E402
from r2s.diagnose.stats.noise import scale_noise_level  # noqa: E402
from r2s.diagnose.stats.ranking import NoiseBar, rank, supported  # noqa: E402


def registration(rng, n: int, spread: float, scale: float, rule: str,
                 prior: tuple = (0.02, 4.0)) -> RegistrationData:
    z = rng.uniform(0.5, 1.2, n)
    logs = rng.normal(0.0, spread, n) + np.log(scale)
    objs = tuple(ScaleObs(i + 1, float(np.exp(v)), float(d), 0.95, 0.001)
                 for i, (v, d) in enumerate(zip(logs, z)))
    if rule == "mad":
        sigma, dof = max(0.01, 1.4826 * float(np.median(np.abs(logs - np.median(logs))))), None
    else:
        sigma, dof = scale_noise_level(logs, 0.01, *prior)
    return RegistrationData(objs, scale_sigma=sigma, scale_floor=0.01, noise_dof=dof,
                            noise_prior=tuple(prior))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--draws", type=int, default=20, help="draws per (objects, spread) cell")
    ap.add_argument("--scale", type=float, default=1.0, help="injected depth scale")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--prior", default="0.02,4", help="prior spread and its worth (objects)")
    ap.add_argument("--rules", default="mad,std,bar", help="which noise rules to run")
    args = ap.parse_args()
    prior = tuple(float(v) for v in args.prior.split(","))
    rules = [r for r in (("mad", None), ("std", None), ("std", NoiseBar(200, 0.99)))
             if (r[0] if r[1] is None else "bar") in args.rules.split(",")]
    depth = {k: v for k, v in all_effects().items() if k.startswith("depth")}
    counts = (3, 4, 5, 6, 8)
    spreads = (0.015, 0.02, 0.03, 0.04)
    print(f"depth scale {args.scale}; cells: objects {counts} x prior spread {spreads}, "
          f"{args.draws} draws each; prior spread {prior[0]} worth {prior[1]}")
    for rule, bar in rules:
        rng = np.random.default_rng(args.seed)
        hits = total = 0
        per_n = {}
        per_spread = {}
        for n in counts:
            for spread in spreads:
                for _ in range(args.draws):
                    res = Residuals(registration=registration(rng, n, spread, args.scale, rule,
                                                              prior))
                    ok = supported(rank(res, depth, noise=bar).best, 2.0)
                    hits += ok
                    total += 1
                    per_n[n] = per_n.get(n, 0) + ok
                    per_spread[spread] = per_spread.get(spread, 0) + ok
        label = f"{rule}{' + noise bar' if bar else ''}"
        detail = ", ".join(f"{n} obj {per_n[n]}/{len(spreads) * args.draws}" for n in counts)
        by_spread = ", ".join(f"{100 * sp:g} % {per_spread[sp]}/{len(counts) * args.draws}"
                              for sp in spreads)
        print(f"{label:16s} supported {hits}/{total} = {hits / total:.3f} ({detail}; "
              f"{by_spread})")


if __name__ == "__main__":
    main()
