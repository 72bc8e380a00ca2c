"""The ``q3t`` command line and the studies built on the solver: run, bench, check, study, sweep.

Nothing else in ``sim`` imports this package; the service's commands (serve, play,
bench-service) live in ``server`` and join ``q3t`` through the ``q3t.commands`` entry points.
"""
