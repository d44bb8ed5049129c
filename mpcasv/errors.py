"""Errors of bad input shared across layers (defined here, below everything that raises them).

:class:`mpcasv.config.ConfigError` covers configuration files; :class:`LogError` covers logs
(DUNE ``.lsf``, identification CSV/Parquet). Both mean "bad input": the command line prints
one line and exits 2.
"""

from __future__ import annotations


class LogError(ValueError):
    """A log that cannot be read; the message names the file and the problem.

    Raised by :mod:`mpcasv.io.lsf` and :mod:`mpcasv.models.identify` (which cannot import the
    I/O layer's error without importing upward)."""
