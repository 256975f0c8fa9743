"""Command-line flags shared by several commands, defined once."""

from __future__ import annotations

import argparse


def add_window_arguments(parser: argparse.ArgumentParser, window_s: float, overlap: float) -> None:
    """``--window-s`` and ``--overlap`` (1-s windows with 50 % overlap by default: the callers' configs)."""
    parser.add_argument("--window-s", type=float, default=window_s, metavar="S",
                        help=f"window length in seconds (default {window_s:g})")
    parser.add_argument("--overlap", type=float, default=overlap, metavar="F",
                        help=f"overlap of consecutive windows, in [0, 1) (default {overlap:g})")
