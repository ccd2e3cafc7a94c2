"""Where li2020 is best: an α × R_e × k1 × k2 sweep of li2020 beside nearest frontier (Li et al. 2020).

Li's planner has four knobs: the effective radius R_e (Eq 5–6: how far a waypoint's gain region
reaches), α (R_u = α·R_e, the entropy map's update radius, Eq 7), and the Eq 8 edge weights k1
(entropy-boundary cells) and k2 (other boundary cells). One ``jaxplore.sweep`` runs every
combination on one world, each setting with the same seeds (start poses), and nearest frontier
with the same seeds as the reference. The figure shows, per (R_e, α) panel, li2020's coverage
per metre (Li's E_r: Li's "Entropy" column is 16 × coverage) over k1 × k2, divided by nearest
frontier's: above 1 (blue) li2020 explores more per metre than nearest frontier; a cross marks
settings where fewer robots than nearest frontier's reached completion.

Usage:
  python experiments/li2020_sweep.py            # lab, 4 seeds, 3 R_e x 3 α x 3 k1 x 2 k2
  python experiments/li2020_sweep.py --quick    # a smoke run: tiny grid of settings, 60 steps
Writes ``experiments/results/li2020_sweep.md`` and ``li2020_sweep.png`` (or ``--out``); the sweep
folder (resumable: ``--resume`` the same command) is ``<out>_runs``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--world", default="lab")
  parser.add_argument("--res", type=float, default=None, help="m/cell (default: the world's)")
  parser.add_argument("--seeds", type=int, default=4)
  parser.add_argument("--r-e", default="1.5,2.85,5.7", help="R_e values, m (static: one compile each)")
  parser.add_argument("--alpha", default="1.0,1.5,2.0")
  parser.add_argument("--k1", default="0.0,0.2,0.5")
  parser.add_argument("--k2", default="0.6,0.9")
  parser.add_argument("--max-steps", type=int, default=None, help="default: the runner's budget")
  parser.add_argument("--devices", type=int, default=1)
  parser.add_argument("--quick", action="store_true")
  parser.add_argument("--slam", choices=("oracle", "scan_matching"), default="oracle",
                      help="the SLAM model of both sweeps (li2020's own is scan_matching, "
                           "nearest frontier's the oracle); li2020_sweep.md was made on oracle")
  parser.add_argument("--out", default=str(RESULTS / "li2020_sweep"), help="<out>.md, <out>.png")
  args = parser.parse_args(argv)
  if args.quick:
    args.seeds, args.r_e, args.alpha, args.k1, args.k2 = 2, "2.85", "1.0,1.5", "0.0,0.5", "0.9"
    args.max_steps = args.max_steps or 60
  os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={args.devices}")

  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  import numpy as np

  import jaxplore

  values = lambda text: [float(v) for v in text.split(",") if v]
  r_es, alphas, k1s, k2s = values(args.r_e), values(args.alpha), values(args.k1), values(args.k2)
  out = Path(args.out)
  runs = out.with_name(out.name + "_runs")
  common = dict(world=args.world, seeds=args.seeds, preset="li2020", res=args.res,
                max_steps=args.max_steps, devices=args.devices, slam=args.slam, quiet=True)
  started = time.perf_counter()
  results = {}
  for name, planner, grid in (
      ("li2020", "li2020", {"r_e": r_es, "alpha": alphas, "k1": k1s, "k2": k2s}),
      ("nearest_frontier", "nearest_frontier", None)):
    folder = runs / name
    if (folder / "sweep_schedule.json").exists():  # an earlier invocation's: finish or reread it
      results[name] = jaxplore.sweep(resume=folder, quiet=True).episodes
    else:
      results[name] = jaxplore.sweep(grid=grid, planner=planner, out=folder, **common).episodes
  li, nf = results["li2020"], results["nearest_frontier"]
  for frame in (li, nf):
    frame["coverage_per_m"] = frame.coverage_m2 / frame.distance_m
  nf_rate = float(nf.coverage_per_m.mean())
  nf_complete = float((nf.reason == "complete").mean())

  keys = ["r_e", "alpha", "k1", "k2"]
  table = li.groupby(keys).agg(coverage_per_m=("coverage_per_m", "mean"),
                               coverage_per_m_std=("coverage_per_m", "std"),
                               coverage=("coverage", "mean"), distance_m=("distance_m", "mean"),
                               E_r=("E_r", "mean"),
                               complete=("reason", lambda r: float((r == "complete").mean())))
  table = table.reset_index()
  table["vs_nearest_frontier"] = table.coverage_per_m / nf_rate

  fig, axes = plt.subplots(len(r_es), len(alphas),
                           figsize=(max(7.0, 3.4 * len(alphas) + 1.5), 3.0 * len(r_es) + 0.8),
                           squeeze=False, sharex=True, sharey=True, layout="constrained")
  norm = matplotlib.colors.TwoSlopeNorm(vcenter=1.0, vmin=min(0.5, table.vs_nearest_frontier.min()),
                                        vmax=max(1.5, table.vs_nearest_frontier.max()))
  for row, r_e in enumerate(r_es):
    for col, alpha in enumerate(alphas):
      ax = axes[row][col]
      cell = table[np.isclose(table.r_e, r_e) & np.isclose(table.alpha, alpha)]
      grid = np.full((len(k2s), len(k1s)), np.nan)
      fewer = np.zeros_like(grid, bool)
      for _, r in cell.iterrows():
        i, j = k2s.index(r.k2), k1s.index(r.k1)
        grid[i, j] = r.vs_nearest_frontier
        fewer[i, j] = r.complete < nf_complete
      image = ax.imshow(grid, origin="lower", cmap="RdBu", norm=norm, aspect="auto")
      for i in range(len(k2s)):
        for j in range(len(k1s)):
          if np.isfinite(grid[i, j]):
            ax.text(j, i, f"{grid[i, j]:.2f}" + (" ×" if fewer[i, j] else ""), ha="center",
                    va="center", fontsize=8)
      ax.set_xticks(range(len(k1s)), [f"{k:g}" for k in k1s])
      ax.set_yticks(range(len(k2s)), [f"{k:g}" for k in k2s])
      ax.set_title(f"R_e {r_e:g} m, α {alpha:g}", fontsize=9)
      if row == len(r_es) - 1:
        ax.set_xlabel("k1")
      if col == 0:
        ax.set_ylabel("k2")
  fig.colorbar(image, ax=axes, shrink=0.8,
               label="coverage per metre, li2020 / nearest frontier")
  fig.suptitle(f"li2020 vs nearest frontier on {args.world}, {args.seeds} seeds per setting\n"
               f"nearest frontier {nf_rate:.3g} m²/m, {nf_complete:.0%} complete; "
               f"× = fewer complete", fontsize=10)
  fig.savefig(out.with_suffix(".png"), dpi=100)

  best = table.sort_values("coverage_per_m", ascending=False)
  columns = keys + ["coverage_per_m", "coverage_per_m_std", "vs_nearest_frontier", "coverage",
                    "distance_m", "E_r", "complete"]
  lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
  for _, r in best.iterrows():
    lines.append("| " + " | ".join(f"{r[c]:.4g}" for c in columns) + " |")
  header = (f"li2020 α × R_e × k1 × k2 on {args.world}, {args.seeds} seeds per setting, preset "
            f"li2020, command: python experiments/li2020_sweep.py {' '.join(argv or sys.argv[1:])}\n"
            f"wall time {time.perf_counter() - started:.0f} s (sweeps reused from {runs} "
            f"not counted)\n\nnearest frontier, same seeds: coverage per metre {nf_rate:.4g} m²/m, "
            f"coverage {nf.coverage.mean():.4g}, distance {nf.distance_m.mean():.4g} m, "
            f"{nf_complete:.0%} complete\n\nSettings, best coverage per metre first "
            f"(vs_nearest_frontier > 1: li2020 explores more per metre):\n\n")
  out.with_suffix(".md").write_text(header + "\n".join(lines) + "\n")
  print(header + "\n".join(lines[:12]))


if __name__ == "__main__":
  main()
