"""The pinch-kernel file is read once per process: `campaign check` and the rails forecast child ask whether the
kernel is there (railcheck.missing_kernel) and then draw the presses with it; each read of the paper kernel is 34 ms.
A file rewritten at the same path is read again, and the shared kernel's arrays cannot be written."""

import json
import subprocess
import sys

import numpy as np
import pytest
from test_electrical_pressed import _paper_at

import neatskin.skin.kernel as kmod
from neatskin.rig.protocol import load_protocol
from neatskin.skin.kernel import KernelSpec, PinchKernel, packaged_kernel_path, read_kernel, write_kernel

COUNTED = """
import json, sys
import neatskin.skin.kernel as k
reads, read = [], k.read_kernel
def counted(path):
    reads.append(str(path))
    return read(path)
k.read_kernel = counted
{call}
print(json.dumps(reads), file=sys.stderr)
"""


def _reads(call: str, env=None) -> tuple[subprocess.CompletedProcess, list[str]]:
    """Run `call` in a fresh interpreter with read_kernel counted: (the process, the paths it read)."""
    done = subprocess.run(
        [sys.executable, "-c", COUNTED.format(call=call)], capture_output=True, text=True, timeout=240, env=env
    )
    assert done.returncode == 0, done.stderr
    return done, json.loads(done.stderr.strip().splitlines()[-1])


def test_check_and_the_forecast_child_read_the_packaged_kernel_once(tmp_path):
    path = _paper_at(tmp_path, "0.0005")
    packaged = str(packaged_kernel_path())
    check, reads = _reads(f"from neatskin.cli import main\nassert main(['campaign', 'check', {str(path)!r}]) == 0")
    assert reads == [packaged]  # 942188f: twice (missing_kernel's load, then the skin's)
    assert "warning: 58 of 2800 presses" in check.stdout
    child, reads = _reads(f"from neatskin.rig.railcheck import main\nassert main([{str(path)!r}]) == 0")
    assert reads == [packaged] and child.stdout.startswith("electrical, pressed (")


def test_a_cached_kernel_is_read_once_beside_the_packaged_one(tmp_path):
    """A 6 mm probe's kernel in the user cache (the paper kernel's table under its key, standing in for a solve):
    check reads the packaged file once (its key differs) and the cached one once (942188f: each twice)."""
    import os

    path = _paper_at(tmp_path, "0.0005")
    path.write_text(path.read_text().replace("probe_diameter_mm = 5.5", "probe_diameter_mm = 6.0"))
    key = KernelSpec.for_layout(load_protocol(path).layout, 3.0).key()
    paper = read_kernel(packaged_kernel_path())
    cached = tmp_path / "cache" / "kernels" / f"{key}.parquet"
    write_kernel(PinchKernel(paper.offsets_mm, paper.depths_mm, paper.area_ratio, paper.force_n, key, "{}"), cached)
    env = {**os.environ, "NEATSKIN_CACHE": str(tmp_path / "cache")}
    check, reads = _reads(f"from neatskin.cli import main\nassert main(['campaign', 'check', {str(path)!r}]) == 0", env)
    assert reads == [str(packaged_kernel_path()), str(cached)]
    assert "first solving" not in check.stdout and "electrical, pressed (" in check.stdout


def test_a_rewritten_kernel_file_is_read_again_and_the_shared_one_is_read_only(tmp_path, monkeypatch):
    monkeypatch.setenv("NEATSKIN_CACHE", str(tmp_path))
    monkeypatch.setattr(kmod, "packaged_kernel_path", lambda: tmp_path / "none.parquet")
    spec = KernelSpec()
    offsets, depths = np.arange(0.0, 10.01, 0.5), np.arange(0.0, 4.01, 0.5)
    file = tmp_path / "kernels" / f"{spec.key()}.parquet"

    def write(c: float) -> None:
        area = np.where(depths[None, :] > 0, c, 1.0) * np.ones((offsets.size, 1))
        write_kernel(PinchKernel(offsets, depths, area, np.zeros_like(area), spec.key(), json.dumps({"c": c})), file)

    write(0.5)
    first, again = kmod.load_kernel(spec, compute=False), kmod.load_kernel(spec, compute=False)
    assert again is first and first.area_ratio[0, 1] == 0.5
    with pytest.raises(ValueError, match="read-only"):
        first.area_ratio[0, 1] = 0.25
    write(0.75)  # the same path, the same size: another change time
    assert kmod.load_kernel(spec, compute=False).area_ratio[0, 1] == 0.75
