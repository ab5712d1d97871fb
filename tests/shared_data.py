"""Where the tests find the shared data (``../shared`` beside the checkout, or ``$ASSEMBLY_AGENT_SHARED``).

Tests that need it are marked ``@needs_shared``: on a fresh clone with nothing beside it they skip with one
visible reason; CI has the folder and runs them.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

SHARED = Path(os.environ.get("ASSEMBLY_AGENT_SHARED") or Path(__file__).resolve().parents[2] / "shared")
REAL = SHARED / "data" / "real"
EXTERNAL = SHARED / "data" / "external"
SKIP_REASON = f"shared data folder not beside the checkout ({SHARED}); CI has it"

needs_shared = pytest.mark.skipif(not (REAL.is_dir() and EXTERNAL.is_dir()), reason=SKIP_REASON)
