"""``python -m hmpc``: the same entry point as the ``hmpc`` console script."""

import sys

from hmpc.tools.cli import main

sys.exit(main())
