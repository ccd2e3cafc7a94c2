"""Ctrl-C taken at safe points: a SIGINT is noted and acted on between JAX calls, never inside one.

Python raises ``KeyboardInterrupt`` at whatever bytecode the main thread runs next. Inside JAX's
tracing, lowering or XLA compilation that leaves the runtime half-built (the interpreter then
crashed with a segmentation fault on exit), and inside a garbage-collection callback it is
swallowed (``Exception ignored in _xla_gc_callback``: the run went on to its end). Within
:func:`deferred`, the first Ctrl-C only sets a flag; the host loops read it with
:func:`requested` / :func:`check` between compiled calls (after a chunk, after the compile) and
stop there, keeping what is finished. A second Ctrl-C exits at once (exit code 130) without
writing anything more. SIGTERM (``kill``, a batch scheduler's stop) is taken the same way, with
its own exit code (143).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from typing import Any

EXIT_CODE = 130  # 128 + SIGINT, what a shell reports for a Ctrl-C'd command

SIGNALS = (signal.SIGINT, signal.SIGTERM)
_state: dict[str, Any] = {"depth": 0, "requested": False, "previous": {}, "signal": signal.SIGINT}


def _on_signal(signum, frame):
  if _state["requested"]:
    print("\njaxplore: interrupted again: stopping at once (nothing more is written)",
          file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(128 + signum)
  _state["requested"], _state["signal"] = True, signum
  print(f"\njaxplore: {signal.Signals(signum).name} received: stopping at the next safe point "
        "(finished work is kept; Ctrl-C again to stop at once)", file=sys.stderr, flush=True)


@contextlib.contextmanager
def deferred():
  """Within the block (in the main thread), Ctrl-C sets the flag :func:`requested` reads instead
  of raising ``KeyboardInterrupt`` wherever Python happens to be. Blocks nest; the outermost one
  restores the previous handler and clears the flag. Elsewhere than the main thread, nothing
  changes."""
  if threading.current_thread() is not threading.main_thread():
    yield
    return
  if _state["depth"] == 0:
    _state["previous"] = {s: signal.signal(s, _on_signal) for s in SIGNALS}
    _state["requested"], _state["signal"] = False, signal.SIGINT
  _state["depth"] += 1
  try:
    yield
  finally:
    _state["depth"] -= 1
    if _state["depth"] == 0:
      for s, previous in _state["previous"].items():
        signal.signal(s, previous)
      _state["requested"] = False


def requested() -> bool:
  """Whether Ctrl-C was pressed within :func:`deferred` (and not yet acted on)."""
  return _state["requested"]


def exit_code() -> int:
  """The exit code of a command stopped by the signal last received within :func:`deferred`
  (130 for Ctrl-C, 143 for SIGTERM)."""
  return 128 + int(_state["signal"])


def check(message: str) -> None:
  """Raises ``KeyboardInterrupt(message)`` if Ctrl-C was pressed within :func:`deferred`."""
  if _state["requested"]:
    raise KeyboardInterrupt(message)


__all__ = ["EXIT_CODE", "SIGNALS", "check", "deferred", "exit_code", "requested"]
