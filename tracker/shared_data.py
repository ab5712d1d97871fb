"""Where the code finds the project's shared data at run time (never copied into the repository).

The shared folder is ``$ASSEMBLY_AGENT_SHARED`` if set, else ``../shared`` beside the checkout. Code that uses it
must work without it (a documented built-in fallback), since a fresh clone may not have it.
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def shared_root() -> Path:
    """The shared data folder (it may not exist)."""
    env = os.environ.get("ASSEMBLY_AGENT_SHARED")
    return Path(env) if env else REPO_ROOT.parent / "shared"


def skin_data_path() -> Path:
    """``data/external/skin/skin_nonskin.npz`` (UCI Skin Segmentation: ``bgr`` uint8 [N, 3] in B, G, R order and
    ``label`` 1 = skin, 0 = non-skin; see the README beside it)."""
    return shared_root() / "data" / "external" / "skin" / "skin_nonskin.npz"
