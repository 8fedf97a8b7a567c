"""``python -m o3d_terrain`` is the ``o3d-terrain`` command."""

import sys

from .cli import main

sys.exit(main())
