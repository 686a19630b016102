"""Figures of the benchmarks: written whole or not at all."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["save_figure"]


def save_figure(fig, path: Path, dpi: int = 120) -> None:
    """Save the matplotlib figure ``fig`` to ``path`` through a temporary file, so that a
    reader never sees a half-written image."""
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    fig.savefig(tmp, dpi=dpi)
    os.replace(tmp, path)
