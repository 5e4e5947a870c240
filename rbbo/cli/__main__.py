"""``python -m rbbo.cli``: the ``rbbo`` command line, as ``python -m rbbo``."""

import sys

from .entry import main

sys.exit(main())
