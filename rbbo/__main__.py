"""``python -m rbbo``: the ``rbbo`` command line."""

import sys

from .cli import main

sys.exit(main())
