"""``python -m mav_observer``: the same as the ``mav-observer`` command."""

from mav_observer.app.cli import main

raise SystemExit(main())
