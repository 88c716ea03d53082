"""Command-line helpers the scripts and packages share."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Callable, Optional


def int_arg(lo: int, hi: Optional[int] = None) -> Callable[[str], int]:
    """An argparse ``type``: an integer in [lo, hi] (no upper bound when ``hi`` is None),
    refused with one line naming the value (``'x' is not an integer``, ``-1 must be >=
    0``, ``0 must be within 2-200``)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if value < lo or (hi is not None and value > hi):
            bound = f">= {lo}" if hi is None else f"within {lo}-{hi}"
            raise argparse.ArgumentTypeError(f"{value} must be {bound}")
        return value

    return parse


def folder_arg(text: str) -> Path:
    """An argparse ``type`` for an output folder (made later if missing): refused with one
    line when the path is an existing file (``mkdir`` would end the run with a traceback
    after the work, or before it with ``FileExistsError``)."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a file, not a folder")
    return path


def file_arg(text: str) -> Path:
    """An argparse ``type`` for an output file (its folders made later if missing): refused
    with one line when the path is a folder or lies under a file, so a long run does not end
    without its output."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a folder, not a file")
    under = next((p for p in path.parents if p.exists()), None)
    if under is not None and not under.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} lies under the file {str(under)!r}")
    return path
