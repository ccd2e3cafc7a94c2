"""GP / Bayesian-optimisation mutual-information exploration (Bai et al. 2016; Li 2020's
"Method 29").

Li et al. 2020 compare their planner against Bai, Wang, Chen & Englot's (Li's ref. 29): predict
the information a scan would bring from a candidate pose with a Gaussian process over poses and
choose by Bayesian optimisation, so that only a few candidates need an expensive virtual scan.
Bai's paper text is not available here; the steps and values follow the authors' released 2-D
code (RobustFieldAutonomyLab, ``explo_bay_opt_2d_turtlebot_demo.cpp``) where it is explicit:

1. Frontier groups: the belief's frontier cells (:func:`jaxplore.mapping.frontier`) in
   8-connected clusters (:func:`jaxplore.graph.labels.clusters`, the ``max_groups`` largest);
   a group's reference cell f is its cell nearest to the cluster's centroid.
2. Candidates: for each reference f, ``n_yaws`` headings ψ (``2πj / n_yaws``) and radii
   ``radius_min, radius_min + radius_step, …`` (``n_radii`` of them; 1.0, 1.5, …, 5.0 m):
   the cell of ``p = f − R·(cos ψ, sin ψ)``, heading ψ (facing f). Valid when p is traversable
   (known free, clear of walls by the robot radius), reachable, not blacklisted, at least
   ``robot_clearance`` from the robot and at least ``frontier_clearance`` (static) from every
   frontier cell.
3. A random order of the valid candidates (drawn from the plan key): the first ``n_train`` are
   the training set, the next ``n_test`` the test set. Fewer than ``min_valid`` valid
   candidates while frontier groups remain: the robot turns in place by ``rescan_angle``
   (counter-clockwise) and plans again after the turn's scans, as the authors' code does when it
   finds no candidate ("Rotate 60 degrees": 0.4 rad/s for 2.6 s, then candidates again); a
   robot's first 190° scan beside a wall often leaves too few. After ``rescan_turns`` such turns
   in a row (a full circle at the defaults), or with no frontier group left, exploration is
   finished (``valid=False``; the engine ends the episode). The authors' loop turns without
   limit and ends exploration by a map-entropy threshold instead; a bounded count keeps a robot
   whose remaining frontiers offer no valid candidate from turning forever.
4. "Mutual information" of a candidate: the gain of a virtual scan from its pose
   (:mod:`jaxplore.virtual_scan`: the lidar, ``n_beams`` beams over the sensor's field of view
   and range, cast into the belief) — the belief's entropy drop in nats (``gain_kind`` 0), the
   newly known area (1) or the newly free area (2, as the authors' code) — divided by the path
   distance robot → candidate, at least ``min_distance`` (the code divides by the Euclidean
   distance; the path is what the robot drives).
5. The GP (:mod:`jaxplore.gp`): Matérn-3/2 over (x, y, ψ) on the training targets normalised to
   mean 0 and std 1; hyper-parameters fitted by maximising the marginal likelihood with optax's
   Adam (``fit_steps`` steps at ``learning_rate``), warm-started from the robot's previous fit
   (the planner's memory). The authors' code refits the GP at every BO iteration with fixed
   hyper-parameters; here they are fitted once per plan and the GP is conditioned on every new
   evaluation.
6. ``bo_iterations`` rounds of Bayesian optimisation: the test candidate of largest GP-UCB
   ``μ + √β_t·σ``, ``β_t = 2 ln(|D| t² π² / (6δ))`` with |D| the valid test candidates,
   gets a virtual scan and joins the evaluated set.
7. The evaluated candidate with the largest MI is the goal; the path is the Dijkstra path to
   it; look-at = its group's reference cell. The planner commits to the goal (it replans when
   the path is done or blocked).

Plan fields: ``gain`` = the goal's MI (units of ``gain_kind`` per metre), ``cost`` = the path
length (m), ``n_candidates`` = valid candidates.
"""

from __future__ import annotations

import dataclasses
import math

import chex
import jax
import jax.numpy as jnp

from jaxplore import gp, mapping, pytrees, sensor, virtual_scan
from jaxplore.frontiers import plan_to, reachable_paths
from jaxplore.graph import labels
from jaxplore.planners import base
from jaxplore.settings import setting


@dataclasses.dataclass(frozen=True)
class Weights:
  """Traced weights of ``gpbo`` (``params.planner[name]``; sweeping them never recompiles)."""

  learning_rate: float = setting(0.05, "Adam's step size for the GP hyper-parameter fit (step 5)",
                                 gt=0)
  delta: float = setting(0.01, "δ of GP-UCB's β_t = 2 ln(|D| t² π² / (6δ)) (step 6)", gt=0, lt=1)
  gain_kind: float = setting(0.0, "MI of a virtual scan (step 4): 0 the entropy drop (nats), "
                             "1 the newly known area, 2 the newly free area (m²)", ge=0, le=2,
                             integer=True)
  min_distance: float = setting(0.25, "floor of the path distance MI is divided by (step 4)",
                                unit="m", gt=0)
  robot_clearance: float = setting(0.25, "candidates closer to the robot are dropped (step 2)",
                                   unit="m", ge=0)
  rescan_angle: float = setting(math.pi / 3, "turn in place when too few candidates (step 3; "
                                "the authors' code: 60°)", unit="rad", gt=0, lt=2 * math.pi)


DEFAULTS = {f.name: f.default for f in dataclasses.fields(Weights)}

MAX_BEAMS = 3600  # one per 0.1°: more resolve nothing a grid map holds, and cost memory


@dataclasses.dataclass(frozen=True)
class Settings:
  """Static settings of ``gpbo`` (they fix shapes and loop lengths).

  Attributes:
    n_yaws: headings per frontier group (the code: 30 in the 3-D version; PLANNERS: 30).
    radius_min, radius_step, n_radii: candidate distances from the group's reference, m.
    max_groups: frontier clusters that get candidates (the largest).
    frontier_clearance: candidates within this distance of a frontier cell are dropped, m.
    n_train: candidates evaluated before the GP is fitted.
    n_test: capacity of the test set the acquisition is maximised over.
    bo_iterations: Bayesian-optimisation rounds (each one more virtual scan).
    fit_steps: Adam steps per hyper-parameter fit.
    min_valid: fewer valid candidates than this make the robot turn in place and rescan.
    rescan_turns: turns in place in a row, without enough candidates, that end the exploration.
    n_beams: beams of a virtual scan (at most :data:`MAX_BEAMS`).
  """

  n_yaws: int = setting(30, "headings per frontier group (step 2)", static=True, ge=1,
                        integer=True)
  radius_min: float = setting(1.0, "nearest candidate distance from a group's reference (step 2)",
                              unit="m", static=True, gt=0)
  radius_step: float = setting(0.5, "step between candidate distances (step 2)", unit="m",
                               static=True, ge=0)
  n_radii: int = setting(9, "candidate distances per heading (step 2)", static=True, ge=1,
                         integer=True)
  max_groups: int = setting(32, "frontier clusters that get candidates, the largest (step 1)",
                            static=True, ge=1, integer=True)
  frontier_clearance: float = setting(0.3, "candidates this close to a frontier cell are dropped "
                                      "(step 2)", unit="m", static=True, ge=0)
  n_train: int = setting(15, "candidates evaluated before the GP is fitted (step 3)",
                         static=True, ge=1, integer=True)
  n_test: int = setting(1024, "capacity of the test set the acquisition is maximised over "
                        "(step 3)", static=True, ge=1, integer=True)
  bo_iterations: int = setting(3, "Bayesian-optimisation rounds, one virtual scan each (step 6)",
                               static=True, ge=0, integer=True)
  fit_steps: int = setting(100, "Adam steps per hyper-parameter fit (step 5)", static=True, ge=1,
                           integer=True)
  min_valid: int = setting(4, "fewer valid candidates make the robot turn in place (step 3)",
                           static=True, ge=1, integer=True)
  rescan_turns: int = setting(6, "turns in place in a row, without enough candidates, that end "
                              "the exploration (step 3)", static=True, ge=0, integer=True)
  n_beams: int = setting(190, "beams of a virtual scan (step 4; at most one per 0.1°)",
                         static=True, ge=1, le=MAX_BEAMS, integer=True)


@pytrees.dataclass(frozen=True)
class Memory:
  """What a robot's ``gpbo`` keeps between plans.

  Attributes:
    raw: f32[3], the GP's unconstrained hyper-parameters, the warm start of the next fit.
    turns: i32, turns in place in a row for want of candidates (step 3 of the module docstring).
  """

  raw: chex.Array
  turns: chex.Array


def init_memory(ctx, params):
  """σ_f² = 1 (the targets are normalised), ℓ = 1 (m and rad), σ_n² = 0.01; no turn yet."""
  return Memory(raw=gp.unconstrain(1.0, 1.0, 0.01), turns=jnp.int32(0))


def turn_in_place(ctx, robot: base.RobotView, angle):
  """A plan that keeps the robot on its cell and turns it by ``angle`` (rad, counter-clockwise).

  The look-at cell lies on the ray along heading + ``angle`` (x = column, y = row) from the
  robot's cell centre, up to 64 cells out (a direction to within a degree) but never past the
  outermost cell centres, so the grid's border shortens the ray instead of bending it. The
  goal is the robot's own cell: a second turn there in a row blacklists that cell as a goal
  (the engine's rule for a goal chosen twice while the robot stands on it), which only takes
  it out of later candidate sets.
  """
  heading = robot.pose[2] + angle
  direction = jnp.stack([jnp.sin(heading), jnp.cos(heading)])
  start = robot.cell.astype(jnp.float32) + 0.5
  upper = jnp.asarray([ctx.height, ctx.width], jnp.float32) - 0.5
  # How far the ray runs along each axis before it leaves [0.5, size - 0.5].
  room = jnp.where(direction > 1e-6, (upper - start) / jnp.maximum(direction, 1e-6),
                   jnp.where(direction < -1e-6,
                             (0.5 - start) / jnp.minimum(direction, -1e-6), jnp.inf))
  reach = jnp.minimum(64.0, jnp.min(room))
  look_at = jnp.floor(start + reach * direction).astype(jnp.int32)
  waypoints = jnp.zeros((ctx.path_capacity, 2), jnp.int32).at[0].set(robot.cell)
  return base.Plan(waypoints=waypoints, length=jnp.int32(1), goal=robot.cell, look_at=look_at,
                   valid=jnp.bool_(True), gain=jnp.float32(0), cost=jnp.float32(0),
                   n_candidates=jnp.int32(0))


def _weights(params) -> dict:
  return {name: params.planner.get(name, value) for name, value in DEFAULTS.items()}


def reference_cells(clusters: labels.Clusters):
  """i32[K, 2]: each cluster's cell nearest to its centroid (ties: first in row-major order)."""
  height, width = clusters.ids.shape
  flat = labels.nearest_to_centroid(clusters, clusters.ids >= 0)
  flat = jnp.minimum(flat, height * width - 1)
  return jnp.stack([flat // width, flat % width], axis=-1).astype(jnp.int32)


def candidate_poses(reference, settings: Settings, res: float):
  """Cells and headings of every (group, heading, radius) candidate, flattened.

  ``p = f − R·(cos ψ, sin ψ)`` from the centre of the reference cell f, in cell units (column
  = x, row = y). Returns (cells i32[C, 2] (row, col), yaw f32[C], group i32[C]) with
  ``C = K · n_yaws · n_radii``.
  """
  k = reference.shape[0]
  yaw = 2.0 * math.pi * jnp.arange(settings.n_yaws, dtype=jnp.float32) / settings.n_yaws
  radius = (settings.radius_min +
            settings.radius_step * jnp.arange(settings.n_radii, dtype=jnp.float32)) / res
  centre = reference.astype(jnp.float32) + 0.5
  rows = centre[:, None, None, 0] - radius[None, None, :] * jnp.sin(yaw)[None, :, None]
  cols = centre[:, None, None, 1] - radius[None, None, :] * jnp.cos(yaw)[None, :, None]
  shape = (k, settings.n_yaws, settings.n_radii)
  cells = jnp.stack([jnp.floor(rows), jnp.floor(cols)], -1).astype(jnp.int32).reshape(-1, 2)
  yaws = jnp.broadcast_to(yaw[None, :, None], shape).reshape(-1)
  group = jnp.broadcast_to(jnp.arange(k, dtype=jnp.int32)[:, None, None], shape).reshape(-1)
  return cells, yaws, group


def plan_gpbo(ctx, view: base.BeliefView, robot: base.RobotView, params, key, memory):
  """One GP/BO planning round for one robot (see the module docstring). Returns (Plan, memory)."""
  settings: Settings = ctx.settings
  w = _weights(params)
  h, wd = ctx.height, ctx.width
  res = ctx.res

  dist, pred = reachable_paths(ctx, view, robot,
                               jnp.where(view.traversable, 1.0, jnp.inf).astype(jnp.float32))
  groups = labels.clusters(view.frontier, settings.max_groups)
  reference = reference_cells(groups)
  cells, yaws, group = candidate_poses(reference, settings, res)
  inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < wd)
  r, c = jnp.clip(cells[:, 0], 0, h - 1), jnp.clip(cells[:, 1], 0, wd - 1)
  clearance_cells = settings.frontier_clearance / res
  near_frontier = mapping.inflate(view.frontier, jnp.float32(clearance_cells),
                                  int(math.floor(clearance_cells + 1e-6)))
  offset = (cells - robot.cell[None, :]).astype(jnp.float32)
  from_robot = jnp.sqrt(jnp.sum(offset * offset, axis=-1)) * res
  path_m = dist[r, c]
  valid = (inside & groups.valid[group] & view.traversable[r, c] & jnp.isfinite(path_m)
           & ~view.blacklist[r, c] & ~near_frontier[r, c] & (from_robot >= w["robot_clearance"]))
  n_valid = jnp.sum(valid).astype(jnp.int32)

  # A random order of the valid candidates: training set first, then the test set.
  n_train, n_test, n_bo = settings.n_train, settings.n_test, settings.bo_iterations
  total = cells.shape[0]
  take = min(n_train + n_test, total)
  order_key = jnp.where(valid, jax.random.uniform(key, (total,)), -1.0)
  order_score, order = jax.lax.top_k(order_key, take)
  picked = order_score >= 0.0
  order = jnp.pad(order, (0, n_train + n_test - take))
  picked = jnp.pad(picked, (0, n_train + n_test - take))

  # Virtual scans: the belief's walls stop the beams.
  framed = sensor.frame_truth(view.occupied)
  tables = virtual_scan.cell_gains(view.logodds, params,
                                   jnp.round(w["gain_kind"]).astype(jnp.int32), res)
  pose_xy = jnp.stack([(c.astype(jnp.float32) + 0.5) * res,
                       (r.astype(jnp.float32) + 0.5) * res], -1)

  def mutual_information(index):
    """MI per metre of candidate ``index`` (into the flattened candidates)."""
    angles = sensor.beam_angles(yaws[index], params.fov, settings.n_beams)
    observed = virtual_scan.cast(framed, (h, wd), c[index].astype(jnp.float32) + 0.5,
                                 r[index].astype(jnp.float32) + 0.5, angles, params.r_max / res)
    gain = virtual_scan.tabulated_gain(tables, observed)
    return gain / jnp.maximum(path_m[index], w["min_distance"])

  inputs = lambda index: jnp.concatenate([pose_xy[index], yaws[index][..., None]], -1)
  test_index = order[n_train:]
  test_x = inputs(test_index)
  n_domain = jnp.sum(picked[n_train:])

  def acquire(t, raw, evaluated, evaluated_y, evaluated_mask, test_open):
    """Bayesian-optimisation round ``t`` (from 1): the open test candidate of largest GP-UCB."""
    y_norm, _, _ = gp.normalise(evaluated_y, evaluated_mask)
    mean, var = gp.posterior(raw, inputs(evaluated), y_norm, evaluated_mask, test_x)
    score = gp.ucb(mean, var, gp.ucb_beta(n_domain, t, w["delta"]))
    best = jnp.argmax(jnp.where(test_open, score, -jnp.inf))
    return test_index[best], test_open[best], test_open.at[best].set(False)

  def fit(raw, evaluated, evaluated_y, evaluated_mask):
    y_norm, _, _ = gp.normalise(evaluated_y, evaluated_mask)
    fitted, _ = gp.fit(raw, inputs(evaluated), y_norm, evaluated_mask, steps=settings.fit_steps,
                       learning_rate=w["learning_rate"])
    usable = jnp.all(jnp.isfinite(fitted)) & (n_valid >= settings.min_valid)
    return jnp.where(usable, fitted, raw)

  # One loop over the evaluation slots, training set first, then the BO rounds, so that the
  # virtual scan, the fit and the posterior each appear once in the compiled program. The
  # branches depend on the slot number only, which is the same for every robot of a batch, so
  # under vmap they stay branches.
  def evaluate(slot, carry):
    evaluated, evaluated_y, evaluated_mask, test_open, raw = carry
    index, ok, test_open = jax.lax.cond(
        slot < n_train,
        lambda: (order[jnp.minimum(slot, n_train - 1)], picked[jnp.minimum(slot, n_train - 1)],
                 test_open),
        lambda: acquire(slot - n_train + 1, raw, evaluated, evaluated_y, evaluated_mask, test_open))
    evaluated = evaluated.at[slot].set(index)
    evaluated_y = evaluated_y.at[slot].set(jnp.where(ok, mutual_information(index), 0.0))
    evaluated_mask = evaluated_mask.at[slot].set(ok)
    raw = jax.lax.cond(slot == n_train - 1, fit, lambda raw, *_: raw, raw, evaluated, evaluated_y,
                       evaluated_mask)
    return evaluated, evaluated_y, evaluated_mask, test_open, raw

  slots = n_train + n_bo
  init = (jnp.zeros((slots,), jnp.int32), jnp.zeros((slots,), jnp.float32),
          jnp.zeros((slots,), bool), picked[n_train:], jnp.asarray(memory.raw, jnp.float32))
  train_index, train_y, train_mask, _, raw = jax.lax.fori_loop(0, slots, evaluate, init)

  best = jnp.argmax(jnp.where(train_mask, train_y, -jnp.inf))
  chosen = train_index[best]
  valid_plan = (n_valid >= settings.min_valid) & train_mask[best]
  goal = cells[chosen]
  waypoints, length, _ = plan_to(ctx, view, robot, pred, goal, valid_plan)
  plan = base.Plan(waypoints=waypoints, length=length, goal=goal, look_at=reference[group[chosen]],
                   valid=valid_plan,
                   gain=jnp.where(valid_plan, train_y[best], 0.0).astype(jnp.float32),
                   cost=jnp.where(valid_plan, path_m[chosen], jnp.inf).astype(jnp.float32),
                   n_candidates=n_valid)
  # Too few candidates while frontier groups remain: turn and look again (step 3).
  rescan = ~valid_plan & jnp.any(groups.valid) & (memory.turns < settings.rescan_turns)
  turn = turn_in_place(ctx, robot, w["rescan_angle"]).replace(n_candidates=n_valid)
  plan = jax.tree.map(lambda a, b: jnp.where(rescan, a, b), turn, plan)
  turns = jnp.where(valid_plan, 0, memory.turns + rescan.astype(jnp.int32))
  return plan, Memory(raw=raw, turns=turns.astype(jnp.int32))


GPBO = base.planner(
    "gpbo", plan_gpbo, defaults=Weights, settings=Settings(), init_memory=init_memory,
    commits=True, summary="Bai et al.'s GP/BO: virtual-scan MI per metre predicted by a GP, "
                          "GP-UCB (Li's Method 29)")
