"""``python -m jaxplore``: the ``jaxplore`` command (:mod:`jaxplore.cli`), for an environment
whose scripts folder is not on the ``PATH``."""

import sys

from jaxplore import cli

if __name__ == "__main__":
  sys.exit(cli.main())
