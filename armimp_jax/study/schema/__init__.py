"""The one description of a trial: a sweep point's settings and sections (``points``), a run's
points from grids, TOML and ``--set`` (``grids``), the trial configs' sections (``config``)."""
