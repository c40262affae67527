"""Start-up stays light: `neatskin --help` and `import neatskin` load no heavy library, the per-press modules load
no scipy, pandas or plotting until they are used, and `--version` still answers."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest

from neatskin.cli import main

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "pandas", "scipy", "matplotlib", "sklearn", "pyarrow", "tqdm", "joblib", "dask")


def modules_after(code: str) -> set[str]:
    """The modules a fresh interpreter holds after running `code`."""
    script = f"import json, sys\n{code}\nprint(json.dumps(sorted(sys.modules)))"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, env=env, cwd=ROOT)
    return set(json.loads(out.stdout.splitlines()[-1]))


def roots(modules: set[str]) -> set[str]:
    return {m.split(".")[0] for m in modules}


def test_help_and_import_load_no_heavy_library():
    loaded = modules_after("import neatskin.cli\nneatskin.cli.build_parser().format_help()")
    assert roots(loaded) & set(HEAVY) == set()
    assert "importlib.metadata" not in loaded  # the version is looked up when asked for
    assert "importlib.metadata" not in modules_after("import neatskin")


def test_per_press_modules_load_numpy_only():
    loaded = modules_after(
        "import neatskin.acquisition.fsr, neatskin.acquisition.features, neatskin.acquisition.demod\n"
        "import neatskin.acquisition.sequence, neatskin.rig.pressrow, neatskin.rig.physlimit"
    )
    assert roots(loaded) & set(HEAVY) == {"numpy"}
    # scipy.ndimage comes with the first press detection, not before
    assert "scipy.ndimage" in modules_after(
        "import numpy as np\nfrom neatskin.acquisition.fsr import detect_presses\ndetect_presses(np.zeros(3000), 1000.0)"
    )


def test_version_is_the_installed_one(capsys):
    try:
        expected = version("neatskin-rig")
    except PackageNotFoundError:
        expected = "0.0.0+unknown"
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out == f"neatskin-rig {expected}\n"
    import neatskin

    assert neatskin.__version__ == expected
    with pytest.raises(AttributeError, match="no attribute 'version'"):
        neatskin.version  # noqa: B018 - the attribute access is the test
