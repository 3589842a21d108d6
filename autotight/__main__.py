"""``python -m autotight …``: the same command line as the ``autotight`` script."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
