"""The package's error for invalid settings (a module of its own, so that any module can raise
it without importing the configuration)."""

import numpy as np


class ConfigError(ValueError):
  """An invalid setting, with a message naming it."""


def shown(values, bad=None, most: int = 4) -> str:
  """The values a refusal names: the distinct ones of ``values`` (a scalar or one per robot;
  those where ``bad`` is set, if given), at most ``most`` of them, then how many more."""
  values = np.asarray(values)
  if bad is not None:
    values = np.broadcast_to(values, np.shape(bad))[np.asarray(bad)]
  distinct = np.unique(values.ravel()).tolist()  # sorted, NaNs as one
  text = ", ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in distinct[:most])
  return text + (f" (and {len(distinct) - most} more)" if len(distinct) > most else "")
