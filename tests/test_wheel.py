"""The packaged defaults work from an installed wheel, from any folder: `skin maps` and `campaign check` from /."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PIP = [sys.executable, "-m", "pip"]


def _source_copy(root: Path) -> Path:
    """What the wheel is built from, copied: setuptools builds in the source's own `build/` folder, so two
    test workers building from the checkout at once remove each other's files (seen: `[Errno 2]` mid-build)."""
    source = root / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(REPO / name, source / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(REPO / "neatskin", source / "neatskin", symlinks=True, ignore=ignore)
    return source


def _shared_folder(tmp_path_factory) -> Path:
    """The session's temporary folder, one for all its xdist workers (each worker's own is a folder in it, as
    pytest-xdist documents for data made once per session); without xdist, the session's own."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@pytest.fixture(scope="session")
def installed(tmp_path_factory) -> Path:
    """The package built as a wheel and installed (without dependencies) into a folder of its own, once per session:
    the first worker to need it builds it under a lock, a worker needing it later (the suite's order may split this
    module's tests) waits for it and takes it (it built its own copy, 4 to 8 s of CPU, before). The tests only read
    the installed folder; each writes in its own tmp_path or reads from /."""
    import fcntl

    shared = _shared_folder(tmp_path_factory)
    root, done = shared / "wheel", shared / "wheel.done"
    wheels, target = root / "wheels", root / "site"
    with open(shared / "wheel.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also if a build below fails
        if not done.is_file():
            shutil.rmtree(root, ignore_errors=True)  # an earlier worker's build that failed half way
            root.mkdir()
            subprocess.run(
                [*PIP, "wheel", "--no-deps", "-q", "-w", str(wheels), str(_source_copy(root))],
                check=True,
                timeout=600,
                cwd=root,
            )
            (wheel,) = wheels.glob("neatskin_rig-*.whl")
            subprocess.run(
                [*PIP, "install", "--no-deps", "-q", "--target", str(target), str(wheel)],
                check=True,
                timeout=600,
                cwd=root,
            )
            done.write_text(wheel.name)
    wheel = wheels / done.read_text()
    names = set(zipfile.ZipFile(wheel).namelist())
    for packaged in ("paper.toml", "smoke.toml", "skins/paper.toml", "wiring/paper.toml", "printers/paper.toml"):
        assert f"neatskin/protocols/{packaged}" in names
    return target


def run_from_root(target: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(target), "MPLBACKEND": "Agg"}
    return subprocess.run(
        [sys.executable, "-m", "neatskin", *args], cwd="/", env=env, capture_output=True, text=True, timeout=600
    )


@pytest.mark.slow
def test_the_package_comes_from_the_wheel(installed):
    env = {**os.environ, "PYTHONPATH": str(installed)}
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            "import neatskin, neatskin.tomlfile as t; print(neatskin.__file__); "
            "print(t.resolve_path('protocols/paper.toml'))",
        ],
        cwd="/",
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.splitlines()
    assert out[0] == str(installed / "neatskin" / "__init__.py")
    assert out[1] == str(installed / "neatskin" / "protocols" / "paper.toml")


@pytest.mark.slow
def test_campaign_check_of_the_packaged_paper_protocol_from_root(installed):
    result = run_from_root(installed, "campaign", "check", "protocols/paper.toml")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == f"{installed / 'neatskin' / 'protocols' / 'paper.toml'}: ok"
    assert lines[1].strip() == "2800 presses (100 positions), layout neatskin-paper (12 channels, 28 pairs)"


@pytest.mark.slow
def test_skin_maps_from_root(installed, tmp_path):
    out = tmp_path / "maps"
    result = run_from_root(installed, "skin", "maps", "--out", str(out), "--grid-step-mm", "1.0", "--no-progress")
    assert result.returncode == 0, result.stderr
    pngs = sorted(p.name for p in out.glob("*.png"))
    parquets = sorted(p.name for p in out.glob("*.parquet"))
    assert pngs and parquets, sorted(p.name for p in out.iterdir())
    assert all((out / name).stat().st_size > 1000 for name in pngs)
