"""``python -m autotight.cli …``: the same command line as the ``autotight`` script."""

import sys

from .main import main

sys.exit(main())
