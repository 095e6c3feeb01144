"""``python -m o3d_ofp``: the command line."""

import sys

from .cli import main

sys.exit(main())
