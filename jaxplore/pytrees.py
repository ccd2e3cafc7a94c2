"""Frozen pytree dataclasses (chex's), spelled so type checkers read their fields."""

import sys

import chex

if sys.version_info >= (3, 11):
  from typing import dataclass_transform
else:  # pragma: no cover
  from typing_extensions import dataclass_transform


@dataclass_transform(frozen_default=True)
def dataclass(*args, **kwargs):
  """:func:`chex.dataclass`: a dataclass that is a JAX pytree."""
  return chex.dataclass(*args, **kwargs)
