"""Shared fixtures: the repo's protocol folder and the paper layout; Ctrl-C reaches the tests' children."""

import signal
from pathlib import Path

import pytest

from neatskin.layout import load_layout

REPO = Path(__file__).resolve().parent.parent
PROTOCOLS = REPO / "protocols"

# A test run started in the background of a script (`pytest ... &`) inherits SIGINT ignored, as POSIX shells
# do for background jobs, and so would every `neatskin` child a test sends Ctrl-C to (Python installs no
# KeyboardInterrupt handler when SIGINT starts ignored): the Ctrl-C tests then wait on a child that never
# stops. Give this process (each xdist worker imports this file) a handler, so its children start with the
# default and get Python's.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session")
def protocols_dir() -> Path:
    return PROTOCOLS


@pytest.fixture(scope="session")
def paper_layout():
    return load_layout(PROTOCOLS / "skins" / "paper.toml")
