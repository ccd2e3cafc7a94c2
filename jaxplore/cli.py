"""The ``jaxplore`` command (also ``python -m jaxplore``): ``run``, ``sweep``, ``maps``, ``plot``,
``animate``.

A thin argparse layer over :func:`jaxplore.runner.run` and friends: ``run`` and ``sweep`` take the
same run settings (:class:`jaxplore.runspec.RunSpec`, whose defaults they show). JAX computes
nothing before the arguments are parsed, so ``--devices`` can set how many host devices XLA
exposes (XLA:CPU runs a loop body on one thread; two devices use both cores).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path


def _number_or_text(value: str, text_allowed: bool):
  """A flag's value: a number, or (``text_allowed``: a planner's static setting such as
  li2020's ``region``) the text itself, which the planner's settings then check."""
  try:
    return float(value)
  except ValueError:
    if text_allowed:
      word = value.strip()
      return {"true": True, "false": False}.get(word.lower(), word)
    raise


def _key_values(items, what, text_allowed=False):
  from jaxplore.config import ConfigError
  out = {}
  for item in items or []:
    if "=" not in item:
      raise ConfigError(f"{what} takes NAME=VALUE, got {item!r}")
    name, value = item.split("=", 1)
    try:
      out[name.strip()] = _number_or_text(value, text_allowed)
    except ValueError:
      raise ConfigError(f"{what} {name}: {value!r} is not a number") from None
  return out


def _parameter_flags(extra, planners):
  """``--NAME VALUE`` / ``--NAME=VALUE`` for any simulator parameter, or weight or setting of one
  of ``planners`` (e.g. ``--alpha 1.5 --k1 0.2``): (params, planner_params). Anything else is an
  error."""
  from jaxplore.config import ConfigError
  from jaxplore.planners import get_planner
  from jaxplore.runspec import SIM_PARAMS, kind_of
  specs = [get_planner(p) for p in planners]
  params, planner_params = {}, {}
  i = 0
  while i < len(extra):
    token = extra[i]
    if not token.startswith("--") or len(token) < 3:
      raise ConfigError(f"unrecognized argument {token!r}")
    name, eq, value = token[2:].partition("=")
    if not eq:
      if i + 1 >= len(extra):
        raise ConfigError(f"{token} needs a value")
      value, i = extra[i + 1], i + 1
    i += 1
    name = name.replace("-", "_")
    kinds = {kind_of(name, spec) for spec in specs} - {None}
    if kinds & {"param", "static"}:
      target = params
    elif kinds:
      target = planner_params
    else:
      weights = sorted({w for spec in specs for w in spec.defaults})
      raise ConfigError(f"unrecognized argument --{name}: not an option, a simulator "
                        f"parameter ({', '.join(SIM_PARAMS)}) nor a weight of planner "
                        f"{' or '.join(repr(p) for p in planners)} "
                        f"({', '.join(weights) or 'none'})")
    try:
      target[name] = _number_or_text(value, kinds == {"setting"})
    except ValueError:
      raise ConfigError(f"--{name}: {value!r} is not a number") from None
  return params, planner_params


def settings_listing(planners=(), names=(), markdown: bool = False) -> str:
  """The text of ``jaxplore settings``: the simulator's settings, then each of ``planners``'
  (``"all"``: every registered planner's), only ``names`` if given."""
  from jaxplore.config import PARAM_SETTINGS, STATIC_SETTINGS, ConfigError
  from jaxplore.planners import get_planner, planner_names
  from jaxplore.runspec import RUN_SETTINGS
  from jaxplore.settings import table
  rows = [*RUN_SETTINGS.values(), *PARAM_SETTINGS.values(), *STATIC_SETTINGS.values()]
  chosen = planner_names() if "all" in planners else list(planners)
  for planner in chosen:
    rows += get_planner(planner).declared_settings()
  if names:
    unknown = sorted(set(names) - {s.name for s in rows})
    if unknown:
      raise ConfigError(f"no setting(s) {unknown}"
                        + ("" if chosen else " of the simulator (a planner's: add --planner NAME)"))
    rows = [s for s in rows if s.name in names]
  if not markdown or names:
    return table(rows, markdown=markdown)
  return SETTINGS_PAGE_INTRO + "\n" + table(rows, markdown=True)


SETTINGS_PAGE_INTRO = """# Settings

Every setting a run or a sweep takes by name: `--set NAME=VALUE` or `--NAME VALUE` on the
command line, a `[set]` table in a TOML file, `params={...}` in Python, a sweep's `--grid` or
`--random`. Nobody needs to say whose a setting is (the simulator's or the planner's).

A **traced** setting may differ robot by robot and is swept without recompiling; each value of a
**static** one fixes the compiled program, so a sweep runs each value as a group of its own.
Presets (`--preset`) change the lidar and the robot (`r_max`, `fov`, `v_max`, `w_max`, ...).
This page is generated from the declarations in the code
(`jaxplore settings --planner all --markdown > docs/settings.md`); `jaxplore settings` prints it
as text.
"""


def _settings(args) -> int:
  """``jaxplore settings``."""
  from jaxplore.config import ConfigError
  try:
    text = settings_listing(args.planner or (), args.names, args.markdown)
  except ConfigError as err:
    print(f"jaxplore: error: {err}", file=sys.stderr)
    return 2
  print(text, end="")
  return 0


def set_host_devices(n=None):
  """Splits the host CPU into ``n`` JAX devices (default: one per core, the CLI's default devices)
  unless ``XLA_FLAGS`` already says; call it before JAX starts."""
  n = n or os.cpu_count() or 1
  flags = os.environ.get("XLA_FLAGS", "")
  if "xla_force_host_platform_device_count" not in flags and n > 1:
    os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={n}".strip()


STALLED_EXIT_CODE = 3


def _reporting_errors(compute):
  """``(compute(), 0)``; a bad setting or map prints ``jaxplore: error: ...`` and gives exit code
  2, results that could not be written after the compute 1 (saying what was written), Ctrl-C
  (results already written are kept) 130, a stalled run (:class:`jaxplore.driver.Watchdog`;
  the results of the finished chunks written) 3. Where a compiled call given up on still runs,
  the process ends at once: a normal interpreter exit would wait for it."""
  from jaxplore import driver, interrupts
  from jaxplore.config import ConfigError
  from jaxplore.errors import OutputError
  from jaxplore.maps import MapError
  try:
    return compute(), 0
  except (ConfigError, MapError) as err:
    print(f"jaxplore: error: {err}", file=sys.stderr)
    return None, 2
  except OutputError as err:
    print(f"jaxplore: error: {err}", file=sys.stderr)
    return None, 1
  except (driver.Stalled, KeyboardInterrupt) as err:
    stalled = isinstance(err, driver.Stalled)
    print(f"jaxplore: {'error: ' if stalled else ''}{err or 'interrupted'}", file=sys.stderr,
          flush=True)
    code = STALLED_EXIT_CODE if stalled else interrupts.exit_code()
    if driver.dropped_call_running():
      sys.stdout.flush()
      os._exit(code)
    return None, code


def _spec_flags(args, extra, planners) -> dict:
  """The run settings given as flags (None where not given), parameter tables included."""
  from jaxplore.runspec import RUN_SETTINGS, SHARED
  params, planner_params = _parameter_flags(extra, planners)
  # words pass: a RunSpec checks each name's values (and moves each to its owner)
  params.update(_key_values(args.set, "--set", text_allowed=True))
  planner_params.update(_key_values(args.planner_set, "--planner-set", text_allowed=True))
  flags = {name: getattr(args, name) for name in RUN_SETTINGS if name in SHARED}
  return dict(flags, start=args.start, slam=args.slam, params=params or None,
              planner_params=planner_params or None, out=args.out, devices=args.devices)


def _run(args, extra) -> int:
  """``jaxplore run``: flags (and ``--config``) -> :func:`jaxplore.runner.run`."""
  from jaxplore.config import ConfigError
  from jaxplore.runspec import RunSpec, load_run_config, merge_settings

  def compute():
    from_file = {} if args.config is None else load_run_config(args.config)
    planner = args.planner or from_file.get("planner") or RunSpec.planner
    robot_seeds = None
    if args.robot_seeds is not None:
      try:
        robot_seeds = [int(v) for v in args.robot_seeds.split(",") if v.strip()]
      except ValueError:
        raise ConfigError(f"--robot-seeds takes integers like 0,3,7, "
                          f"got {args.robot_seeds!r}") from None
    explicit = dict(world=args.world, planner=args.planner, robots=args.robots, seed=args.seed,
                    robot_seeds=robot_seeds, **_spec_flags(args, extra, [planner]))
    settings = merge_settings(from_file, explicit)
    set_host_devices(settings.get("devices"))  # before JAX starts
    from jaxplore.runner import run
    out, devices = settings.pop("out"), settings.pop("devices")
    return run(out=out, devices=devices, progress=not args.no_progress, **settings)

  result, code = _reporting_errors(compute)
  if code:
    return code
  t, c = result.timing, result.config
  print(f"compile {t['compile_s']:.1f} s, run {t['run_s']:.1f} s, {_speed(t)} on "
        f"{c['sharded_over']} x {c['device_kind']} ({c['sim_config']['strategy']})")
  if result.out is not None:
    print(f"results in {result.out}")
  return 0


def _speed(timing: dict) -> str:
  """Robot-steps per second, or seconds per robot-step where that rate would round to 0."""
  steps, run_s = timing["robot_steps"], timing["run_s"]
  if not steps or not run_s > 0:
    return "no robot-steps run"
  rate = steps / run_s
  return f"{rate:.0f} robot-steps/s" if rate >= 10 else f"{run_s / steps:.3g} s per robot-step"


def _sweep(args, extra) -> int:
  """``jaxplore sweep``: flags -> :func:`jaxplore.sweeps.sweep` (None = from --config or
  default)."""
  from jaxplore import sweeps
  from jaxplore.config import ConfigError
  from jaxplore.runspec import RunSpec

  def compute():
    config = None if args.config is None else sweeps.load_config(args.config)  # read once: a pipe
    devices = args.devices if args.devices is not None else (config or {}).get("devices")
    set_host_devices(devices)  # before JAX starts
    grid = None
    for item in args.grid or []:
      if "=" not in item:
        raise ConfigError(f"--grid takes NAME=V1,V2,..., got {item!r}")
      name, values = item.split("=", 1)
      try:
        grid = dict(grid or {}, **{name.strip(): [_number_or_text(v, True)
                                                   for v in values.split(",") if v.strip()]})
      except ValueError:
        raise ConfigError(f"--grid {name}: {values!r} is not a list of numbers") from None
    random = None
    for item in args.random or []:
      if "=" not in item:
        raise ConfigError(f"--random takes NAME=LOW:HIGH[:log], got {item!r}")
      name, spec = item.split("=", 1)
      random = dict(random or {}, **{name.strip(): sweeps.parse_random_spec(spec)})
    one = lambda names: None if names is None else (names[0] if len(names) == 1 else names)
    planners = args.planner or (config or {}).get("planner") or RunSpec.planner
    settings = _spec_flags(args, extra, planners if isinstance(planners, list) else [planners])
    return sweeps.sweep(
        grid=grid, seeds=args.seeds, world=one(args.world), planner=one(args.planner),
        quiet=args.quiet, random=random, samples=args.samples, random_seed=args.random_seed,
        chunk_size=args.chunk_size, resume=args.resume, config=config,
        progress=not args.no_progress, distributed=args.distributed, **settings)

  result, code = _reporting_errors(compute)
  if code:
    return code
  t = result.timing
  print(f"{t['robot_episodes']} robot-episodes ({t['chunks_run']} of {t['chunks']} chunks "
        f"run here, {t['chunks_skipped']} already done); compile {t['compile_s']:.1f} s "
        f"({t['compiles']} compile(s)), run {t['run_s']:.1f} s")
  if result.out is not None:
    print(f"results in {result.out}")
  return 0


def _add_setting_flag(p, name: str, declaration) -> None:
  """``--NAME`` for a declared run setting (:data:`jaxplore.runspec.RUN_SETTINGS`): its type,
  choices and help from the declaration; unset (None) unless given."""
  from jaxplore.settings import default_text
  default = declaration.unset if declaration.default is None else default_text(declaration)
  help_text = f"{declaration.help} (default: {default})"
  flag = "--" + name.replace("_", "-")
  if declaration.boolean:
    p.add_argument(flag, action="store_true", default=None, help=help_text)
  elif declaration.choices:
    p.add_argument(flag, choices=declaration.choices, default=None, help=help_text)
  else:
    p.add_argument(flag, type=int if declaration.integer else float, default=None,
                   help=help_text)


def _add_spec_flags(p):
  """The run settings shared by ``jaxplore run`` and ``jaxplore sweep`` (defaults: RunSpec's)."""
  from jaxplore.runspec import RUN_SETTINGS, SHARED
  for name, declaration in RUN_SETTINGS.items():
    if name in SHARED:
      _add_setting_flag(p, name, declaration)
  p.add_argument("--start", default=None,
                 help="x,y[,theta] start for every robot (default: random)")
  p.add_argument("--slam", choices=("oracle", "scan_matching"), default=None,
                 help="the setting slam: the SLAM model, oracle (relocalised by its true pose) or "
                 "scan_matching (scan matching against its own map, loop closures, pose-graph "
                 "optimisation; turns --pose-noise on). Default: oracle")
  p.add_argument("--set", action="append", metavar="NAME=VALUE",
                 help="any setting, the simulator's or the planner's ('jaxplore settings' lists "
                 "them; or pass it as --NAME VALUE, e.g. --alpha 1.5 --k1 0.2)")
  p.add_argument("--planner-set", action="append", metavar="NAME=VALUE",
                 help="the same as --set (kept for older scripts)")
  p.add_argument("--devices", type=int, default=None,
                 help="host devices to shard over (default: cores)")
  p.add_argument("--no-progress", action="store_true")


class _Parser(argparse.ArgumentParser):
  """An argument parser whose ``run`` and ``sweep`` help ends with the registered planners.

  The registry is imported only when the help is shown: importing the planners starts JAX,
  which must wait until ``--devices`` has set the host device count."""

  def format_help(self):
    text = super().format_help()
    if self.prog.split()[-1] not in ("run", "sweep"):
      return text
    from jaxplore.planners.base import get_planner, planner_names
    rows = [f"  {name:<18} {get_planner(name).summary}" for name in planner_names()]
    return text + "\nplanners (--planner NAME):\n" + "\n".join(rows) + "\n"


def build_parser() -> argparse.ArgumentParser:
  parser = _Parser(prog="jaxplore", epilog="--plugin FILE.py|MODULE (before or after the "
                   "command, repeatable): load the planners a file or module registers (also "
                   "$JAXPLORE_PLUGINS, and installed packages' 'jaxplore.planners' entry points).",
                   description="Batched exploration and active-SLAM simulator: "
                   "run a batch of robots, sweep settings, list worlds and settings, redraw "
                   "figures, animate a run. 'jaxplore COMMAND --help' for each command.")
  sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

  run = sub.add_parser("run", help="run a batch of robots exploring a world",
                       description="Any simulator parameter or planner weight is also a flag: "
                       "--NAME VALUE (e.g. --alpha 1.5 --k1 0.2).")
  from jaxplore.runspec import RunSpec
  run.add_argument("--config", default=None, metavar="TOML",
                   help="settings from a TOML file (the keys of a sweep file; flags win)")
  run.add_argument("--world", default=None,
                   help=f"built-in world name or map_server YAML path (default {RunSpec.world})")
  run.add_argument("--planner", default=None, help=f"planner (default {RunSpec.planner})")
  from jaxplore.runspec import RUN_SETTINGS
  _add_setting_flag(run, "robots", RUN_SETTINGS["robots"])
  run.add_argument("--seed", type=int, default=None, help=f"PRNG seed (default {RunSpec.seed})")
  run.add_argument("--robot-seeds", default=None, metavar="S1,S2,...",
                   help="one PRNG seed per robot instead of --seed (robot b starts as seed b does "
                   "in a sweep)")
  run.add_argument("--out", default=None, help="results folder")
  _add_spec_flags(run)

  sw = sub.add_parser(
      "sweep", help="worlds x planners x parameter settings x seeds, in resumable chunks",
      description="Every combination of --grid values (and --samples random points of the --random "
      "ranges) x seeds, for every world and planner. Runs in chunks of equal shape (one compile "
      "per world and planner); with --out every finished chunk is saved, and --resume DIR "
      "finishes an interrupted sweep. Flags given here win over the --config file.")
  sw.add_argument("--config", default=None, metavar="TOML", help="sweep settings from a TOML file")
  sw.add_argument("--resume", default=None, metavar="DIR",
                  help="finish the interrupted sweep in DIR (every setting comes from its "
                  "schedule)")
  sw.add_argument("--world", nargs="+", default=None, metavar="WORLD",
                  help=f"one or more worlds: names or map_server YAML paths "
                  f"(default {RunSpec.world})")
  sw.add_argument("--planner", nargs="+", default=None, metavar="PLANNER",
                  help=f"one or more planners (default {RunSpec.planner})")
  sw.add_argument("--grid", nargs="+", default=None, metavar="NAME=V1,V2,...",
                  help="values of each swept parameter, e.g. alpha=1.0,1.5 k1=0,0.2 k2=0.6,0.9 "
                       "(words for a planner's word-valued setting: region=visible,disc)")
  sw.add_argument("--random", nargs="+", default=None, metavar="NAME=LOW:HIGH[:log]",
                  help="random search ranges (uniform, or log-uniform with :log)")
  sw.add_argument("--samples", type=int, default=None,
                  help="random points drawn from the --random ranges")
  sw.add_argument("--random-seed", type=int, default=None,
                  help="seed of the random points (default 0)")
  sw.add_argument("--seeds", type=int, default=None, help="seeds per setting (default 8)")
  sw.add_argument("--chunk-size", type=int, default=None,
                  help="robot-episodes per chunk (default: at most 256, as many as fit in memory)")
  sw.add_argument("--out", default=None, help="results folder (schedule, chunks, tables, figures)")
  sw.add_argument("--distributed", action="store_true",
                  help="call jax.distributed.initialize() and split the chunks over the processes")
  sw.add_argument("--quiet", action="store_true", help="no per-setting table")
  _add_spec_flags(sw)

  settings = sub.add_parser(
      "settings", help="list every setting: default, range, unit, traced or static",
      description="Every setting a run or a sweep takes by name (--set NAME=VALUE, --NAME VALUE, "
      "a TOML [set] table, a sweep's --grid): traced ones may differ robot by robot and are "
      "swept without recompiling; each value of a static one is a compiled program of its own.")
  settings.add_argument("names", nargs="*", metavar="NAME", help="only these settings")
  settings.add_argument("--planner", action="append", default=None, metavar="PLANNER",
                        help="also this planner's weights and settings ('all': every planner's)")
  settings.add_argument("--markdown", action="store_true", help="as Markdown tables")

  maps = sub.add_parser("maps", help="list the built-in worlds, or render one to PNG")
  maps.add_argument("--render", default=None, metavar="WORLD", help="world name or YAML path")
  maps.add_argument("--res", type=float, default=None)
  maps.add_argument("--out", default=None, help="PNG path for --render")

  plot = sub.add_parser("plot", help="redraw the figures of a results folder")
  plot.add_argument("run_dir")

  anim = sub.add_parser("animate", help="GIF/MP4 of chosen robots of a run (re-simulated)",
                        description="Re-simulates the chosen robots of a results folder from its "
                        "config.json, checks the replay against curves.parquet, and draws belief, "
                        "trajectory and current path per robot, one frame per planning round or "
                        "every N steps.")
  anim.add_argument("run_dir")
  anim.add_argument("--robots", default="0", help="comma-separated robot indices (default: 0)")
  anim.add_argument("--every", type=int, default=None,
                    help="steps between frames, rounded up to whole planning rounds "
                    "(default: at most 150 frames)")
  anim.add_argument("--out", default=None,
                    help="FILE.gif or FILE.mp4 (default: RUN_DIR/animation_<robots>.gif)")
  anim.add_argument("--fps", type=float, default=8.0)
  anim.add_argument("--no-progress", action="store_true")
  return parser


def _take_plugins(argv) -> list[str]:
  """``argv`` without its ``--plugin FILE_OR_MODULE`` options, whose values are added to the
  planner plugins (:data:`jaxplore.planners.base.PLUGINS_ENV`; loaded when the registry is
  first read, so ``--help`` lists their planners and sweep workers inherit them)."""
  from jaxplore.planners.base import PLUGINS_ENV
  argv, rest, plugins = list(sys.argv[1:] if argv is None else argv), [], []
  i = 0
  while i < len(argv):
    name, eq, value = argv[i].partition("=")
    if name == "--plugin":
      if not eq:
        if i + 1 >= len(argv):
          raise SystemExit("jaxplore: error: --plugin needs a file or module")
        value, i = argv[i + 1], i + 1
      plugins.append(str(Path(value).resolve()) if value.endswith(".py") else value)
    else:
      rest.append(argv[i])
    i += 1
  if plugins:
    known = [p for p in os.environ.get(PLUGINS_ENV, "").split(os.pathsep) if p]
    os.environ[PLUGINS_ENV] = os.pathsep.join(known + plugins)
  return rest


def main(argv=None) -> int:
  argv = _take_plugins(argv)
  parser = build_parser()
  args, extra = parser.parse_known_args(argv)
  if extra and args.command not in ("run", "sweep"):
    parser.error(f"unrecognized arguments: {' '.join(extra)}")
  if args.command in ("run", "sweep"):
    from jaxplore import interrupts
    with interrupts.deferred():  # Ctrl-C acted on between JAX calls, start-up included
      return (_run if args.command == "run" else _sweep)(args, extra)
  if args.command == "settings":
    return _settings(args)
  if args.command == "maps":
    from jaxplore.maps import MapError, load_world, render_png, world_table
    if args.render:
      from jaxplore.errors import ConfigError, check_writable
      try:
        if args.out is not None and not args.out.lower().endswith(".png"):
          raise ConfigError(f"--out {args.out!r}: the rendering is a PNG; give a .png file")
        grid = load_world(args.render, res=args.res)
        out = args.out or f"{grid.name}.png"
        check_writable(out, "--out")
      except (ConfigError, MapError) as err:
        print(f"jaxplore: error: {err}", file=sys.stderr)
        return 2
      try:
        Path(out).absolute().parent.mkdir(parents=True, exist_ok=True)
        render_png(grid, out)
      except OSError as err:
        print(f"jaxplore: error: could not write {out!r}: {err.strerror or err}", file=sys.stderr)
        return 1
      print(f"wrote {out}")
      return 0
    rows = world_table()
    print(f"{'world':<11} {'cells W x H':>11} {'res':>5} {'extent (m)':>12} {'free m²':>8} "
          f"{'reachable m²':>12}  description")
    for r in rows:
      print(f"{r['name']:<11} {r['width_cells']:>5} x {r['height_cells']:<4} {r['res']:>5.2g} "
            f"{r['width_m']:>5.1f} x {r['height_m']:<5.1f} {r['free_m2']:>8.0f} "
            f"{r['reachable_m2']:>12.0f}  {r['description']}")
    return 0
  if args.command == "animate":
    from jaxplore.animate import animate
    from jaxplore.config import ConfigError
    from jaxplore.maps import MapError
    try:
      path = animate(args.run_dir, robots=args.robots, out=args.out, every=args.every, fps=args.fps,
                     progress=not args.no_progress)
    except (ConfigError, MapError) as err:
      print(f"jaxplore: error: {err}", file=sys.stderr)
      return 2
    print(f"wrote {path}")
    return 0
  if args.command == "plot":
    from jaxplore import plot
    from jaxplore.config import ConfigError
    try:
      paths = plot.run_figures(args.run_dir)
    except ConfigError as err:
      print(f"jaxplore: error: {err}", file=sys.stderr)
      return 2
    for path in paths:
      print(f"wrote {path}")
    return 0
  return 1


if __name__ == "__main__":
  sys.exit(main())
