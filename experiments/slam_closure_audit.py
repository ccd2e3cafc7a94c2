"""The scan_matching SLAM model's keyframe edges and loop closures, audited against the truth.

One batch of robots (nearest frontier, seed 0, one device) stepped a chunk at a time; at the end,
every loop closure is compared with the truth's relative pose (its translation and heading error,
beside the match's own standard deviations and the drift covariance that sized and gated its
search, read at the chunk before it closed), and the chain of odometry edges is checked for
calibration: the normalised estimation error squared (NEES) of each edge (1 per component if its
covariance is honest) and the heading drift over windows of ``--window`` edges, actual against
what the edges' covariances claim when compounded as independent measurements; and the drift
since the last closure or link (the newest keyframe's ``keyframe_drift``, which gates the
closures) against the estimate's error relative to that keyframe's
(``experiments/results/slam_drift_calibration.md``).

A closure is *bad* here when its measured relative pose is off by more than ``--bad-m`` metres or
``--bad-deg`` degrees (the ``false`` column of the results is a different test: the truth outside
the closure's own 99 % bound). The table of thresholds on the match's positional standard
deviation shows how many good and bad closures each would keep.

Usage:
  python experiments/slam_closure_audit.py --world willow --robots 4 --epochs 500
  python experiments/slam_closure_audit.py --world intel --robots 4 --epochs 500 \
      --set loop_max_variance=3.0
Prints markdown; ``--out FILE`` also writes it.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED_MAPS = HERE.parent.parent / "shared" / "maps"
WORLDS = {"willow": str(SHARED_MAPS / "willow.yaml"), "intel": str(SHARED_MAPS / "intel.yaml"),
          "fr_campus": str(SHARED_MAPS / "fr_campus.yaml")}
RES = {"willow": 0.2, "intel": 0.2, "fr_campus": 0.5}  # fr_campus: the li2020 table's cells
SD_THRESHOLDS = (0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 1.0)
CHI2_THRESHOLDS = (3.0, 7.81, 11.34, 16.27, 25.0, 100.0)


def _between(a, b):
  """Each pose of ``b`` in the frame of the matching pose of ``a`` (rows of poses, numpy):
  :func:`jaxplore.motion.between` over the rows."""
  import jax

  from jaxplore import motion
  return np.asarray(jax.vmap(motion.between)(np.atleast_2d(a).astype(np.float32),
                                             np.atleast_2d(b).astype(np.float32)))


def _last_restart(graph):
  """Per robot, the newer keyframe of its last loop edge the back end kept (0 before any): what
  the drift counted from before the graph recorded it (``drift_from``)."""
  loops, n_loops = np.asarray(graph.loops), np.asarray(graph.n_loops)
  revoked = np.asarray(graph.loop_revoked)
  out = np.zeros(loops.shape[0], np.int64)
  for r in range(loops.shape[0]):
    kept = [j for j in range(int(n_loops[r])) if not revoked[r, j]]
    out[r] = loops[r, kept[-1], 1] if kept else 0
  return out


def simulate(world: str, robots: int, epochs: int, settings: dict):
  """The final pose graphs and, per chunk, each robot's loop count, drift covariance and pose
  error."""
  import jax

  from jaxplore import driver, sim
  from jaxplore.resolve import resolve
  from jaxplore.runspec import RunSpec

  resolved = resolve(RunSpec.create(world=WORLDS.get(world, world), res=RES.get(world),
                                    robots=robots, planner="nearest_frontier", seed=0,
                                    slam="scan_matching", params=settings or None))
  config = resolved.config
  params = sim.broadcast_params(resolved.params, robots)
  keys = jax.random.split(jax.random.PRNGKey(0), robots)
  state = sim.reset_batch(config, resolved.world, params, keys, None)
  advance = driver.compiled_advance(config, 1, 1)
  log = []
  for _ in range(min(epochs, config.n_epochs)):
    state, _ = advance(resolved.world, params, state)
    pose, est = np.asarray(state.pose), np.asarray(state.pose_est)
    g = state.graph
    since = (np.asarray(g.drift_from) if getattr(g, "drift_from", None) is not None
             else _last_restart(g))
    rows = np.arange(robots)
    log.append(dict(n_loops=np.asarray(g.n_loops).copy(),
                    drift=np.asarray(g.keyframe_drift)[rows, np.asarray(g.n_nodes) - 1].copy(),
                    pose_error=np.hypot(*(pose[:, :2] - est[:, :2]).T),
                    # What the drift is counted from: its keyframe's estimate and truth now.
                    keyframes_since=np.asarray(g.n_nodes) - 1 - since,
                    from_est=np.asarray(g.poses)[rows, since],
                    from_true=np.asarray(g.truth)[rows, since],
                    est=est.copy(), pose=pose.copy()))
    if bool(np.all(np.asarray(state.done))):
      break
  return jax.tree.map(np.asarray, state.graph), log


def final_chi2(graph, r: int):
  """Robot ``r``'s loop edges' ``rᵀ Ω r`` (:func:`jaxplore.slam.model.loop_chi2`) at the optimum
  of its final graph (re-optimised: near links made since its last closure are in it; revoked
  edges are not)."""
  import jax
  import jax.numpy as jnp

  from jaxplore.slam import model, optimiser
  g = jax.tree.map(lambda a: None if a is None else jnp.asarray(a[r]), graph)
  valid = jnp.arange(g.poses.shape[0]) < g.n_nodes
  result = optimiser.optimise(g.poses, valid, model.graph_edges(g), max_iterations=50,
                              loop_capacity=min(model.WOODBURY_LOOPS, g.loops.shape[0]),
                              cg_max_iterations=50)
  return np.asarray(model.loop_chi2(g.replace(poses=jnp.where(valid[:, None], result.poses,
                                                                 g.poses))))


def audit(graph, log, bad_m: float, bad_deg: float, window: int):
  """The closures (list of dicts) and the chain's calibration per robot (list of dicts)."""
  closures, chains = [], []
  n_robots = graph.n_nodes.shape[0]
  for r in range(n_robots):
    n = int(graph.n_nodes[r])
    chi2 = final_chi2(graph, r)
    truth = _between(graph.truth[r, :n - 1], graph.truth[r, 1:n])
    err = graph.chain_measured[r, 1:n] - truth
    err[:, 2] = (err[:, 2] + np.pi) % (2 * np.pi) - np.pi
    cov = np.linalg.inv(graph.chain_info[r, 1:n].astype(np.float64))
    nees_theta = err[:, 2] ** 2 / cov[:, 2, 2]
    nees_xy = np.einsum("ni,nij,nj->n", err[:, :2], np.linalg.inv(cov[:, :2, :2]), err[:, :2])
    summed = np.concatenate([[0.0], np.cumsum(err[:, 2])])
    claimed = np.concatenate([[0.0], np.cumsum(cov[:, 2, 2])])
    w = min(window, n - 1)
    actual = summed[w:] - summed[:-w]
    chains.append(dict(robot=r, edges=n - 1, nees_xy=nees_xy.mean(), nees_theta=nees_theta.mean(),
                       drift_actual_deg=np.degrees(np.sqrt(np.mean(actual ** 2))),
                       drift_claimed_deg=np.degrees(np.sqrt(np.mean(claimed[w:] - claimed[:-w])))))
    for j in range(int(graph.n_loops[r])):
      older, newer = graph.loops[r, j]
      e = graph.loop_measured[r, j] - _between(graph.truth[r, older], graph.truth[r, newer])[0]
      e[2] = (e[2] + np.pi) % (2 * np.pi) - np.pi
      lcov = np.linalg.inv(graph.loop_info[r, j].astype(np.float64))
      chunk = next((k for k, row in enumerate(log) if row["n_loops"][r] > j), len(log) - 1)
      drift = log[max(chunk - 1, 0)]["drift"][r]
      closures.append(dict(
          robot=r, loop=j, older=int(older), newer=int(newer), chunk=chunk,
          error_m=float(np.hypot(e[0], e[1])), error_deg=float(np.degrees(e[2])),
          match_sd_m=float(np.sqrt(np.linalg.eigvalsh(lcov[:2, :2]).max())),
          match_sd_deg=float(np.degrees(np.sqrt(lcov[2, 2]))),
          drift_sd_m=float(np.sqrt(max(drift[0, 0], drift[1, 1]))),
          drift_sd_deg=float(np.degrees(np.sqrt(drift[2, 2]))),
          false=bool(graph.loop_false[r, j]),
          link=bool(graph.loop_link[r, j]) if graph.loop_link is not None else False,
          bad=bool(np.hypot(e[0], e[1]) > bad_m or abs(np.degrees(e[2])) > bad_deg),
          revoked=bool(graph.loop_revoked[r, j]), chi2=float(chi2[j]),
          chi2_last=float(graph.loop_chi2[r, j]),
          pose_error_before=float(log[max(chunk - 1, 0)]["pose_error"][r]),
          pose_error_after=float(log[chunk]["pose_error"][r])))
  return closures, chains


def drift_calibration(log, min_keyframes: int):
  """Per robot, the drift covariance (which sizes and gates the loop search) against the error
  it stands for, at every chunk with at least ``min_keyframes`` keyframes since the last closure
  or link: the estimate's error relative to that keyframe's, in the world frame (the relative
  pose of the two estimates less the truth's, turned by the older estimate's heading)."""
  rows = []
  for r in range(log[0]["est"].shape[0]):
    nees_xy, nees_theta, err_deg, sd_deg = [], [], [], []
    for row in log:
      if row["keyframes_since"][r] < min_keyframes:
        continue
      a_est, a_true = row["from_est"][r], row["from_true"][r]
      rel = _between(a_est, row["est"][r])[0] - _between(a_true, row["pose"][r])[0]
      rel[2] = (rel[2] + np.pi) % (2 * np.pi) - np.pi
      c, s = np.cos(a_est[2]), np.sin(a_est[2])
      xy = np.array([[c, -s], [s, c]]) @ rel[:2]
      cov = row["drift"][r].astype(np.float64)
      nees_xy.append(xy @ np.linalg.solve(cov[:2, :2], xy))
      nees_theta.append(rel[2] ** 2 / cov[2, 2])
      err_deg.append(np.degrees(abs(rel[2])))
      sd_deg.append(np.degrees(np.sqrt(cov[2, 2])))
    if nees_xy:
      rows.append(dict(robot=r, chunks=len(nees_xy), nees_xy=float(np.mean(nees_xy)),
                       nees_theta=float(np.mean(nees_theta)),
                       outside=float(np.mean(np.array(nees_theta) > 9.0)),
                       err_deg=float(np.sqrt(np.mean(np.square(err_deg)))),
                       sd_deg=float(np.sqrt(np.mean(np.square(sd_deg))))))
  return rows


def report(closures, chains, log, header: str, bad_m: float, bad_deg: float) -> str:
  pose_error = np.stack([row["pose_error"] for row in log])
  calibration = drift_calibration(log, 20)
  lines = [header, "",
           f"Pose error over every chunk of every robot: mean {pose_error.mean():.3f} m, "
           f"95th percentile {np.percentile(pose_error, 95):.2f} m, max {pose_error.max():.2f} m; "
           "final per robot " + ", ".join(f"{x:.2f}" for x in pose_error[-1]) + " m.", "",
           "## The chain of odometry edges", "",
           "| robot | edges | NEES x-y (2 if honest) | NEES θ (1) | heading drift over the window:"
           " actual rms ° | claimed (independent edges) ° |", "|---:|---:|---:|---:|---:|---:|"]
  for c in chains:
    lines.append(f"| {c['robot']} | {c['edges']} | {c['nees_xy']:.2f} | {c['nees_theta']:.2f} | "
                 f"{c['drift_actual_deg']:.2f} | {c['drift_claimed_deg']:.2f} |")
  lines += ["", "## The drift since the last closure or link, against its error", "",
            "At every chunk with at least 20 keyframes since the last closure or link: the "
            "estimate's error relative to that keyframe's against the newest keyframe's drift "
            "(`keyframe_drift`), which gates the loop closures (NEES 2 in x-y, 1 in θ if honest; a "
            "tenth of the chunks outside 3σ in θ would be many).", "",
            "| robot | chunks | NEES x-y (2) | NEES θ (1) | θ outside 3σ | heading error rms ° | "
            "drift sd rms ° |", "|---:|---:|---:|---:|---:|---:|---:|"]
  for c in calibration:
    lines.append(f"| {c['robot']} | {c['chunks']} | {c['nees_xy']:.2f} | {c['nees_theta']:.2f} | "
                 f"{c['outside']:.1%} | {c['err_deg']:.2f} | {c['sd_deg']:.2f} |")
  lines += ["", "## Which loop edges the back end's χ² test would catch", "",
            "Each loop edge's `rᵀ Ω r` at the optimum of its robot's final graph (revoked edges "
            "left out; for them, the value at the optimisation that revoked them), against "
            "whether it is bad; `loop_revoke_chi2` revokes above its value.", "",
            "| edges | χ² above | bad caught | good caught | revoked: bad / good |",
            "|---|---:|---:|---:|---:|"]
  for kind, group in (("closures", [c for c in closures if not c["link"]]),
                      ("near links", [c for c in closures if c["link"]])):
    chi2 = np.array([c["chi2_last"] if c["revoked"] else c["chi2"] for c in group])
    bad_edge = np.array([c["bad"] for c in group], bool)
    revoked = np.array([c["revoked"] for c in group], bool)
    for th in CHI2_THRESHOLDS:
      over = chi2 > th
      lines.append(f"| {kind} | {th} | {int(np.sum(over & bad_edge))} / {int(bad_edge.sum())} | "
                   f"{int(np.sum(over & ~bad_edge))} / {int(np.sum(~bad_edge))} | "
                   f"{int(np.sum(revoked & bad_edge))} / {int(np.sum(revoked & ~bad_edge))} |")
  links = [c for c in closures if c["link"]]
  closures = [c for c in closures if not c["link"]]
  bad = [c for c in closures if c["bad"]]
  lines += ["", f"## Near links: {len(links)}, of which {sum(c['bad'] for c in links)} bad, "
            f"{sum(c['false'] for c in links)} false"]
  lines += ["", f"## Loop closures: {len(closures)}, of which {len(bad)} bad (> {bad_m} m or "
            f"> {bad_deg}°), {sum(c['false'] for c in closures)} false", "",
            "| match positional sd at most (m) | good kept | bad kept |", "|---:|---:|---:|"]
  n_good = len(closures) - len(bad)
  for th in SD_THRESHOLDS:
    kept = [c for c in closures if c["match_sd_m"] <= th]
    lines.append(f"| {th} | {sum(not c['bad'] for c in kept)} / {n_good} | "
                 f"{sum(c['bad'] for c in kept)} / {len(bad)} |")
  lines += ["", "The bad closures:", "",
            "| robot | keyframes | chunk | error m | error ° | match sd m / ° | drift sd m / ° | "
            "false | pose error before -> after m |", "|---:|---|---:|---:|---:|---|---|---|---|"]
  for c in bad:
    lines.append(f"| {c['robot']} | {c['older']} -> {c['newer']} | {c['chunk']} | "
                 f"{c['error_m']:.2f} | {c['error_deg']:.1f} | {c['match_sd_m']:.2f} / "
                 f"{c['match_sd_deg']:.1f} | {c['drift_sd_m']:.2f} / {c['drift_sd_deg']:.1f} | "
                 f"{c['false']} | {c['pose_error_before']:.2f} -> {c['pose_error_after']:.2f} |")
  return "\n".join(lines) + "\n"


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--world", default="willow")
  parser.add_argument("--robots", type=int, default=4)
  parser.add_argument("--epochs", type=int, default=500, help="planning rounds to run at most")
  parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
  parser.add_argument("--bad-m", type=float, default=0.3)
  parser.add_argument("--bad-deg", type=float, default=4.0)
  parser.add_argument("--window", type=int, default=150, help="edges per heading-drift window")
  parser.add_argument("--out", default=None)
  args = parser.parse_args(argv)
  settings = {}
  for item in args.set:
    name, _, value = item.partition("=")
    settings[name.strip()] = float(value)
  started = time.time()
  graph, log = simulate(args.world, args.robots, args.epochs, settings)
  closures, chains = audit(graph, log, args.bad_m, args.bad_deg, args.window)
  command = (f"python experiments/slam_closure_audit.py --world {args.world} --robots "
             f"{args.robots} --epochs {args.epochs}" + "".join(f" --set {s}" for s in args.set))
  text = report(closures, chains, log, f"# `{command}` ({len(log)} chunks, "
                f"{time.time() - started:.0f} s)", args.bad_m, args.bad_deg)
  print(text)
  if args.out:
    Path(args.out).write_text(text)


if __name__ == "__main__":
  main()
