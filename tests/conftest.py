"""Shared fixtures: the repo's protocol folder and the paper layout."""

from pathlib import Path

import pytest

from neatskin.layout import load_layout

REPO = Path(__file__).resolve().parent.parent
PROTOCOLS = REPO / "protocols"


@pytest.fixture(scope="session")
def protocols_dir() -> Path:
    return PROTOCOLS


@pytest.fixture(scope="session")
def paper_layout():
    return load_layout(PROTOCOLS / "skins" / "paper.toml")
