"""Shared fixtures: the repo's protocol folder, the paper layout and the smoke reference run; Ctrl-C reaches the tests'
children; no Hypothesis deadline; the suite's start order under xdist and the early work it starts (tests/early.py)."""

import os
import signal
from collections.abc import Callable
from pathlib import Path

import early
import pytest
import suite_order
from hypothesis import settings
from suite_order import block_sizes, long_first
from threadpoolctl import threadpool_limits

from neatskin.layout import load_layout

# Under xdist each worker is one of `-n` processes sharing the cores: numerical libraries on one thread each, as
# joblib gives its workers (neatskin.baselines.tasks.THREAD_VARS), and so every process a test starts (early work,
# `neatskin` children) inherits. On 2 cores, 2 workers with OpenMP's and OpenBLAS's default of a thread per core
# ran 4 threads that spin at every barrier for a core a neighbour holds: scikit-learn's kNN search in `design
# validate` took twice the CPU (test_the_study_agrees...: 20 to 25 s against 11 s, load 10 to 14) and the 0.25 mm
# host solves 63.5 s against 37.9 s, their strains bit for bit the same. A variable already set is kept, and a test
# that sets its own limit (threadpoolctl) still gets it.
_ONE_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")
if os.environ.get("PYTEST_XDIST_WORKER") and not any(var in os.environ for var in _ONE_THREAD_VARS):
    os.environ.update(dict.fromkeys(_ONE_THREAD_VARS, "1"))
    threadpool_limits(1)  # the libraries loaded before this line (numpy's OpenBLAS: pytest-randomly, the imports above)

REPO = Path(__file__).resolve().parent.parent
PROTOCOLS = REPO / "protocols"

# A test run started in the background of a script (`pytest ... &`) inherits SIGINT ignored, as POSIX shells
# do for background jobs, and so would every `neatskin` child a test sends Ctrl-C to (Python installs no
# KeyboardInterrupt handler when SIGINT starts ignored): the Ctrl-C tests then wait on a child that never
# stops. Give this process (each xdist worker imports this file) a handler, so its children start with the
# default and get Python's.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# Hypothesis' default deadline (200 ms an example) is a timed assertion: on a loaded machine an example's first run
# overran it and its replay did not, and the test failed as Flaky. Speed lives in benchmarks/; no example has a
# deadline (a test's own @settings inherits this, as conftest is imported before the test modules).
settings.register_profile("neatskin-suite", deadline=None)
settings.load_profile("neatskin-suite")


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node) -> None:
    """xdist's controller tells each worker its scheduling mode (a worker's own `dist` option reads "no")."""
    node.workerinput["neatskin_dist"] = node.config.getoption("dist")


@pytest.hookimpl(trylast=True)  # after -m/-k deselection: the blocks are of the tests that run
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under xdist's worksteal (pyproject's addopts), each worker's first block starts with its share of the
    longest tests (tests/suite_order.py). Every worker collects, and so orders, alike."""
    suite_order.SELECTED = {item.nodeid for item in items}
    workerinput = getattr(config, "workerinput", None)
    if workerinput is None or workerinput.get("neatskin_dist") != "worksteal":
        return
    n_workers = int(workerinput["workercount"])
    items[:] = long_first(items, [item.nodeid for item in items], n_workers)
    # this worker's first block (worksteal hands block k to worker k): its tests' early work starts now, beside the
    # real-firmware tests it starts with (tests/early.py)
    k = int(str(workerinput["workerid"]).removeprefix("gw"))
    first = sum(block_sizes(len(items), n_workers)[:k])
    for item in items[first : first + block_sizes(len(items), n_workers)[k]]:
        early.start(item.nodeid)


def pytest_sessionfinish(session: pytest.Session) -> None:
    early.stop()


@pytest.fixture(scope="session")
def protocols_dir() -> Path:
    return PROTOCOLS


@pytest.fixture(scope="session")
def paper_layout():
    return load_layout(PROTOCOLS / "skins" / "paper.toml")


def shared_folder(tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], object]) -> Path:
    """The folder `name`, made once per test session and shared by its xdist workers: the first worker to ask calls
    `make(folder)` on a new, empty folder under a lock (in the session's temporary folder, which holds each worker's
    own, as pytest-xdist documents for data made once per session); a worker asking while it is being made waits
    for it, and one asking later takes it as made. A `make` that fails leaves nothing: the next one to ask makes it
    again (and fails as loudly). For read-only inputs (a reference run the tests read or copy): made per worker,
    each was made twice whenever the suite's order split its tests over the workers."""
    import fcntl
    import shutil

    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder, done = shared / "shared" / name, shared / "shared" / f"{name}.done"
    folder.parent.mkdir(exist_ok=True)
    with open(shared / "shared" / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also when make fails
        if not done.is_file():
            shutil.rmtree(folder, ignore_errors=True)  # a failed make's remains
            folder.mkdir()
            make(folder)
            done.touch()
    return folder


def _tree_state(folder: Path) -> dict[str, str]:
    """Every file under folder (but Python's byte-code caches), by relative path, with the sha256 of its bytes."""
    import hashlib

    return {
        str(path.relative_to(folder)): hashlib.sha256(path.read_bytes()).hexdigest()
        for path in sorted(folder.rglob("*"))
        if path.is_file() and "__pycache__" not in path.parts
    }


@pytest.fixture(scope="session")
def smoke_reference(tmp_path_factory):
    """The smoke campaign, uninterrupted, without a report (faults_helpers.write_reference: a `neatskin` child),
    made once per session for the test_faults_* and test_campaign_edges modules, which read it or copy it (each
    module made its own, then each worker; now the workers share it: shared_folder). At the end of each worker's
    session it must be as it was made: a test that changed it fails here, naming the files."""
    import json

    from faults_helpers import write_reference

    def make(root: Path) -> None:
        write_reference(root / "run")
        (root / "made.json").write_text(json.dumps(_tree_state(root / "run")))

    root = shared_folder(tmp_path_factory, "smoke-reference", make)
    folder = root / "run"
    yield folder
    made, now = json.loads((root / "made.json").read_text()), _tree_state(folder)
    changed = sorted(name for name in made.keys() | now.keys() if made.get(name) != now.get(name))
    assert not changed, f"a test changed the shared smoke reference run ({folder}): {changed}"


WORKER_PRESSES = 512  # the batching writer's threshold: the smallest campaign that gets a skin worker by default


def write_worker_protocol(root: Path, *, paper_like: bool) -> Path:
    """A copy of smoke.toml with its hardware files under root: 512 presses (8 positions x 64 repeats), features
    only (the dry run's skin worker takes it by default); `paper_like`: the paper-like scene, so every per-press
    condition (placement, depth jitter, drift, dents) reaches the worker."""
    import shutil

    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(PROTOCOLS / sub, root / sub)
    text = (PROTOCOLS / "smoke.toml").read_text()
    text = text.replace("count = 6", "count = 8").replace("repeats = 2", "repeats = 64")
    text = text.replace("waveforms = true", "waveforms = false").replace('signal = "waveforms"', 'signal = "features"')
    if paper_like:
        text = text.replace('preset = "ideal"', 'preset = "paper-like"').replace("placement_error_mm = 0.0\n", "")
    path = root / "worker.toml"
    path.write_text(text)
    return path
