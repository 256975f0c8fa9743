"""Workflow config files for the workflow tests: a YAML writer and a short simulated sequence entry."""

from __future__ import annotations

from pathlib import Path

import yaml


def write_config(path: Path, data: dict) -> Path:
    """Write ``data`` as a YAML config file at ``path``; returns ``path``."""
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def sim_entry(name: str, **kw) -> dict:
    """A config entry for a 3-second simulated sequence; ``kw`` adds or overrides its keys."""
    return {"name": name, "source": "simulate", "duration_s": 3, "seed": 1, **kw}
