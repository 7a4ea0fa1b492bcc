"""Where the models keep what they build once (meshes, training runs): the user's cache,
``$XDG_CACHE_HOME/artifem/<name>`` (the XDG base directory specification; ``~/.cache``
when the variable is unset, empty or not an absolute path)."""

from __future__ import annotations

import os
from pathlib import Path


def user_cache(name: str) -> Path:
    """The cache directory ``name`` of artifem's models (not created here)."""
    base = os.environ.get("XDG_CACHE_HOME", "")
    root = Path(base) if base and os.path.isabs(base) else Path.home() / ".cache"
    return root / "artifem" / name
