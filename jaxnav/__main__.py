"""``python -m jaxnav``: the ``jaxnav`` command (:mod:`jaxnav.cli`)."""

import sys

from jaxnav.cli import main

if __name__ == "__main__":
    sys.exit(main())
