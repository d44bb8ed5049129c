"""Where the project's shared inputs are, for every test: ``../shared`` beside the checkout
(``/work/main``, CI's clean checkout) or beside the worktrees' folder (``/work/wt/NAME``).

``SHARED`` is None when it is not found; tests that need it are skipped then (a missing
optional resource) with ``needs_shared``, and say so in the skip reason.
"""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED: Path | None = next((p / "shared" for p in ROOT.parents[:2]
                            if (p / "shared" / "cases").is_dir()), None)  # fmt: skip
_MISSING = Path("/nonexistent/shared")
CASES = (SHARED or _MISSING) / "cases"  # failing inputs, one folder per case (README each)
DATA = (SHARED or _MISSING) / "data"  # real DUNE data (README there)
needs_shared = pytest.mark.skipif(
    SHARED is None, reason="../shared (cases and data) not found beside the checkout")
