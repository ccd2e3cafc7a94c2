"""The package's errors: invalid settings, and outputs that cannot be written (a module of its
own, so that any module can raise them without importing the configuration)."""

import os
from pathlib import Path

import numpy as np


class ConfigError(ValueError):
  """An invalid setting, with a message naming it."""


class OutputError(OSError):
  """Results that could not be written after the compute (a full disk, a folder gone), with a
  message saying which files were written and which are missing."""


def check_writable(path, what: str) -> None:
  """Refuses, before any compute, an output ``path`` (a file or folder, existing or to be made)
  that cannot be written: a parent that is a file, a read-only filesystem, no permission."""
  path = Path(path).absolute()
  existing = path
  while not existing.exists() and existing != existing.parent:
    existing = existing.parent
  if existing != path and not existing.is_dir():
    raise ConfigError(f"{what} {str(path)!r}: {str(existing)!r} is a file, not a folder")
  folder = existing if existing.is_dir() else existing.parent
  if not os.access(folder, os.W_OK | os.X_OK):
    raise ConfigError(f"{what} {str(path)!r}: {str(folder)!r} is not writable (a read-only "
                      f"filesystem, or no permission)")
  if existing == path and path.is_file() and not os.access(path, os.W_OK):
    raise ConfigError(f"{what} {str(path)!r} is not writable")


def shown(values, bad=None, most: int = 4) -> str:
  """The values a refusal names: the distinct ones of ``values`` (a scalar or one per robot;
  those where ``bad`` is set, if given), at most ``most`` of them, then how many more."""
  values = np.asarray(values)
  if bad is not None:
    values = np.broadcast_to(values, np.shape(bad))[np.asarray(bad)]
  distinct = np.unique(values.ravel()).tolist()  # sorted, NaNs as one
  text = ", ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in distinct[:most])
  return text + (f" (and {len(distinct) - most} more)" if len(distinct) > most else "")
