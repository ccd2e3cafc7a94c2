"""Every user setting declared once: default, range, unit, owner, help, traced or static.

A setting is a dataclass field whose metadata holds a :class:`Setting`, made by :func:`setting`:
the traced parameters (:class:`jaxplore.config.Params`) and the static simulator settings
(:class:`jaxplore.config.SimConfig`) declare theirs where they are defined, e.g. ::

  r_max: Any = setting(15.0, "the lidar's range", owner="lidar", unit="m", gt=0)

From these declarations come the checks of every value (:meth:`Setting.check`), which names a
sweep may vary without recompiling (:attr:`Setting.static`), the listing of ``jaxplore settings``
and the documentation's settings page (:func:`table`). Checks that relate two settings (the
lidar's range against the buffers sized for it) stay with the code that sizes them.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from jaxplore.errors import ConfigError, shown

# A closed upper bound admits this relative excess: a float32 2π or π lies just above the
# float64 one.
_TOLERANCE = 1e-6


@dataclasses.dataclass(frozen=True)
class Setting:
  """The declaration of one setting.

  Attributes:
    default: its value when none is given.
    help: one line for listings and documentation.
    owner: the component it belongs to (``"lidar"``, ``"robot"``, ``"slam"``, ...; a planner's
      declarations leave it empty: the planner is their owner).
    unit: its unit (``"m"``, ``"rad"``, ``"s"``, ``"log-odds"``, ...), or ``""``.
    static: a value fixes the compiled program (a shape or a loop bound): each value of it is a
      program of its own, so a batch takes one value and a sweep groups rows by it. Otherwise it
      is traced: a leaf of :class:`jaxplore.config.Params`, one value per robot if need be.
    low, high: bounds of its range, or None; ``low_open`` / ``high_open``: the bound itself is
      excluded.
    integer: a whole number (a count or a size).
    choices: the words it may take (a word-valued setting), else empty.
    objects: a type whose instances it takes besides its words (a sensor object for ``sensor``,
      which names one), or None.
    boolean: a switch, true or false.
    host: used on the host only (metrics, progress), never by the compiled program.
    unset: what leaving it unset (None) means, where it may be left unset (the value is then
      derived: from the world, the preset, the sensor range, ...); empty: it always has a value.
    name: its name (the field's, filled in by :func:`declared`, unless given).
  """

  default: Any
  help: str
  owner: str
  unit: str = ""
  static: bool = False
  low: float | None = None
  low_open: bool = False
  high: float | None = None
  high_open: bool = False
  integer: bool = False
  choices: tuple[str, ...] = ()
  objects: type | None = None
  boolean: bool = False
  host: bool = False
  unset: str = ""
  name: str = ""

  @property
  def kind(self) -> str:
    """``"static"``, ``"traced"`` or ``"host"`` (see the attributes)."""
    return "host" if self.host else "static" if self.static else "traced"

  @property
  def range_text(self) -> str:
    """The range in words: ``"> 0"``, ``"in (0, 0.5)"``, ``"a positive integer"``, ``"one of a,
    b"``, ``"true or false"``, or ``"any"``."""
    if self.boolean:
      return "true or false"
    if self.choices:
      return "one of " + ", ".join(self.choices)
    low, high = self.low, self.high
    if self.integer and high is None and low in (0, 1) and not self.low_open:
      return "a positive integer" if low == 1 else "a non-negative integer"
    if low is not None and high is not None:
      text = (f"in {'(' if self.low_open else '['}{_number_text(low)}, {_number_text(high)}"
              f"{')' if self.high_open else ']'}")
    elif low is not None:
      text = f"{'>' if self.low_open else '>='} {_number_text(low)}"
    elif high is not None:
      text = f"{'<' if self.high_open else '<='} {_number_text(high)}"
    else:
      text = "any"
    return f"an integer {text}" if self.integer else text

  def check(self, value, what: str | None = None) -> None:
    """Raises :class:`ConfigError` naming the setting when ``value`` (a scalar or an array of
    per-robot values) is not a finite number in range, not whole where it must be, not a switch
    or not one of the choices. ``what`` names it in the message (default ``"parameter NAME"``).
    None passes where the setting may be left unset."""
    what = what or f"parameter {self.name}"
    if value is None and (self.unset or self.default is None):
      return
    if self.boolean:
      if not isinstance(value, (bool, np.bool_)):
        raise ConfigError(f"{what} must be true or false, got {value!r}")
      return
    if self.objects is not None and isinstance(value, self.objects):
      return
    if self.choices:
      if value not in self.choices:
        raise ConfigError(f"{what} must be {self.range_text}, got {value!r}")
      return
    expected = self.range_text if self.integer else "a number"
    if value is None or isinstance(value, (str, bytes, bool, np.bool_)):
      raise ConfigError(f"{what} must be {expected}, got {value!r}")
    try:
      arr = np.asarray(value, np.float64)
    except (TypeError, ValueError):
      raise ConfigError(f"{what} must be {expected}, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
      raise ConfigError(f"{what} is NaN or infinite: {shown(arr, ~np.isfinite(arr))}")
    bad = ~self.within(arr)
    if self.integer:
      bad |= arr != np.round(arr)
    if np.any(bad):
      raise ConfigError(f"{what} must be {self.range_text}, got {shown(arr, bad)}")

  def within(self, arr: np.ndarray) -> np.ndarray:
    """Which elements of ``arr`` lie in the range."""
    ok = np.ones(np.shape(arr), bool)
    if self.low is not None:
      ok &= (arr > self.low) if self.low_open else (arr >= self.low)
    if self.high is not None:
      slack = _TOLERANCE * max(1.0, abs(self.high))
      ok &= (arr < self.high) if self.high_open else (arr <= self.high + slack)
    return ok

  def convert(self, value, what: str | None = None):
    """A checked value (:meth:`check`) as the setting holds it: an int for an integer setting,
    a float or a word otherwise."""
    self.check(value, what)
    if value is None or self.choices or self.objects is not None:
      return value
    if self.boolean:
      return bool(value)
    return int(round(float(value))) if self.integer else float(value)


def _number_text(value: float) -> str:
  for multiple, text in ((1, "π"), (2, "2π"), (0.5, "π/2")):
    if math.isclose(value, multiple * math.pi):
      return text
  return str(int(value)) if float(value).is_integer() and abs(value) < 1e15 else f"{value:g}"


def setting(default, help: str, *, owner: str = "", unit: str = "", static: bool = False,
            gt: float | None = None, ge: float | None = None, lt: float | None = None,
            le: float | None = None, integer: bool = False, choices: Iterable[str] = (),
            objects: type | None = None, boolean: bool = False, host: bool = False,
            unset: str = "", name: str = "") -> Any:
  """A dataclass field declaring a setting (see :class:`Setting`): ``gt``/``ge`` and
  ``lt``/``le`` give its open or closed bounds; ``name``, the setting's name where it cannot
  be the field's (a Python keyword such as ``lambda``)."""
  if gt is not None and ge is not None or lt is not None and le is not None:
    raise TypeError("give one lower bound (gt or ge) and one upper bound (lt or le)")
  declaration = Setting(default=default, help=help, owner=owner, unit=unit, static=static,
                        low=gt if gt is not None else ge, low_open=gt is not None,
                        high=lt if lt is not None else le, high_open=lt is not None,
                        integer=integer, choices=tuple(choices), objects=objects,
                        boolean=boolean,
                        host=host, unset=unset, name=name)
  return dataclasses.field(default=default, metadata={"setting": declaration})


def declared(cls) -> dict[str, Setting]:
  """The settings a dataclass declares (:func:`setting` fields), by name (the field's, unless
  the declaration names itself), in field order."""
  out = {}
  for field in dataclasses.fields(cls):
    declaration = field.metadata.get("setting")
    if declaration is not None:
      name = declaration.name or field.name
      out[name] = dataclasses.replace(declaration, name=name)
  return out


def table(settings: Iterable[Setting], markdown: bool = False) -> str:
  """A listing of ``settings`` grouped by owner (in order of first appearance): name, traced or
  static, default and unit, range, help; as Markdown tables with ``markdown``."""
  rows = list(settings)
  lines = []
  for owner in dict.fromkeys(s.owner for s in rows):
    group = [s for s in rows if s.owner == owner]
    if markdown:
      lines += [f"### {owner}", "", "| name | kind | default | range | meaning |",
                "|---|---|---|---|---|"]
      for s in group:
        help_text = s.help.replace("|", "\\|")
        lines.append(f"| `{s.name}` | {s.kind} | {default_text(s)} | {s.range_text} | "
                     f"{help_text} |")
      lines.append("")
    else:
      lines.append(f"{owner}:")
      cells = [(s.name, s.kind, default_text(s), s.range_text, s.help) for s in group]
      widths = [max(len(c[i]) for c in cells) for i in range(4)]
      for c in cells:
        lines.append("  " + "  ".join(f"{c[i]:<{widths[i]}}" for i in range(4)) + "  " + c[4])
  return "\n".join(line.rstrip() for line in lines).rstrip() + "\n"


def default_text(s: Setting) -> str:
  """A setting's default as listings show it (with its unit; what unset means)."""
  value = s.default
  if value is None:
    return f"unset: {s.unset}" if s.unset else "unset"
  if isinstance(value, bool):
    return "true" if value else "false"
  text = (_number_text(value) if value else "0") if isinstance(value, float) else str(value)
  return f"{text} {s.unit}" if s.unit else text


# A length that sizes buffers (lidar range, robot radius, R_e, R_u, loop radius) may reach
# this far, or across the map's diagonal if that is longer: beyond the diagonal it reaches no
# more cells, only sizes buffers for cells that do not exist.
LENGTH_LIMIT_M = 100.0


def check_length(name: str, value, limit: float, sizes: str, length: str | None = None) -> None:
  """Raises :class:`ConfigError` naming parameter ``name`` when the ``length`` it gives (m; a
  scalar or one per robot; default: the parameter itself), which sizes ``sizes``, is NaN,
  infinite, negative or beyond ``limit`` metres."""
  arr = np.asarray(value, np.float64)
  if not np.all(np.isfinite(arr)):
    raise ConfigError(f"parameter {name} is NaN or infinite: {shown(arr, ~np.isfinite(arr))}")
  if np.any(arr < 0):
    raise ConfigError(f"parameter {name} must be >= 0, got {shown(arr, arr < 0)}")
  if np.any(arr > limit):
    raise ConfigError(f"parameter {name}: {length or name} = {float(arr.max()):.4g} m sizes "
                      f"{sizes}, and "
                      f"may be at most the map's diagonal or {LENGTH_LIMIT_M:g} m, whichever is "
                      f"longer ({limit:.4g} m here): beyond the map it reaches no more cells")


__all__ = ["LENGTH_LIMIT_M", "Setting", "check_length", "declared", "default_text", "setting",
           "table"]
