"""``python -m bench.accuracy``: see :mod:`bench.accuracy.cli`."""

import sys

from .cli import main

sys.exit(main())
