"""``python -m sea3d``: the same as the ``sea3d`` command."""

import sys

from sea3d.cli import main

sys.exit(main())
