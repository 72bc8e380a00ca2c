"""``python -m sim.apps``: the ``q3t`` command."""

from sim.apps.cli import main

raise SystemExit(main())
