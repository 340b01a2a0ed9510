"""Sweeps and what they print: the sweep (``sweep``), tidy tables, figures, saved metrics, the
statistics, the friction threshold and the coverage studies."""

from .. import _folder_getattr

__getattr__ = _folder_getattr(__name__, "sweep")  # 3.2.0's module study.sweep is this folder's sweep now
