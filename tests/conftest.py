"""Shared fixtures: the real HDM05 data (``../shared/data/hdm05``, or the bundled subset)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED_HDM05 = Path(os.environ.get("MIRRORCOACH_HDM05", REPO.parent / "shared" / "data" / "hdm05"))
BUNDLED_HDM05 = REPO / "data" / "hdm05"


@pytest.fixture(scope="session")
def hdm05() -> Path:
    """The full HDM05 dev data (11 classes, actors bd, bk, dg)."""
    if not (SHARED_HDM05 / "amc").is_dir():
        pytest.fail(f"HDM05 data not found at {SHARED_HDM05}; set MIRRORCOACH_HDM05")
    return SHARED_HDM05


@pytest.fixture(scope="session")
def dev_clips(hdm05):
    from shared.io import find_clips, load_clip

    return [load_clip(f) for f in find_clips([hdm05 / "amc"])]


@pytest.fixture(scope="session")
def dev_split(dev_clips):
    """The issue's split: learn from actors bd and bk, test on actor dg."""
    train = [c for c in dev_clips if "_dg_" not in c.name]
    test = [c for c in dev_clips if "_dg_" in c.name]
    return train, test


@pytest.fixture(scope="session")
def dev_space(dev_split):
    from shared.pss.space import ProtoSymbolSpace

    return ProtoSymbolSpace.build(dev_split[0], dim=3)


@pytest.fixture(scope="session")
def bundled() -> Path:
    return BUNDLED_HDM05
