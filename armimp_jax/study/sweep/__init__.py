"""Sweeps and what they print: the sweep (``sweep``), tidy tables, figures, saved metrics, the
statistics, the friction threshold and the coverage studies."""
