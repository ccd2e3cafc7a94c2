"""Ctrl-C taken at safe points: a SIGINT is noted and acted on between JAX calls, never inside one.

Python raises ``KeyboardInterrupt`` at whatever bytecode the main thread runs next. Inside JAX's
tracing, lowering or XLA compilation that leaves the runtime half-built (the interpreter then
crashed with a segmentation fault on exit), and inside a garbage-collection callback it is
swallowed (``Exception ignored in _xla_gc_callback``: the run went on to its end). Within
:func:`deferred`, the first Ctrl-C only sets a flag; the host loops read it with
:func:`requested` / :func:`check` between compiled calls (after a chunk, after the compile) and
stop there, keeping what is finished. A second Ctrl-C exits at once (exit code 130) without
writing anything more.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

EXIT_CODE = 130  # 128 + SIGINT, what a shell reports for a Ctrl-C'd command

_state = {"depth": 0, "requested": False, "previous": None}


def _on_sigint(signum, frame):
  if _state["requested"]:
    print("\njaxplore: interrupted again: stopping at once (nothing more is written)",
          file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(EXIT_CODE)
  _state["requested"] = True
  print("\njaxplore: interrupt received: stopping at the next safe point (finished work is kept; "
        "Ctrl-C again to stop at once)", file=sys.stderr, flush=True)


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
    _state["previous"] = signal.signal(signal.SIGINT, _on_sigint)
    _state["requested"] = False
  _state["depth"] += 1
  try:
    yield
  finally:
    _state["depth"] -= 1
    if _state["depth"] == 0:
      signal.signal(signal.SIGINT, _state["previous"])
      _state["requested"] = False


def requested() -> bool:
  """Whether Ctrl-C was pressed within :func:`deferred` (and not yet acted on)."""
  return _state["requested"]


def check(message: str) -> None:
  """Raises ``KeyboardInterrupt(message)`` if Ctrl-C was pressed within :func:`deferred`."""
  if _state["requested"]:
    raise KeyboardInterrupt(message)


__all__ = ["EXIT_CODE", "check", "deferred", "requested"]
