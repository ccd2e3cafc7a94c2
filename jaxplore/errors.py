"""The package's error for invalid settings (a module of its own, so that any module can raise
it without importing the configuration)."""


class ConfigError(ValueError):
  """An invalid setting, with a message naming it."""
