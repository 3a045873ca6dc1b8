"""``python -m mav_observer``: the same as the ``mav-observer`` command."""

from mav_observer.cli import main

raise SystemExit(main())
