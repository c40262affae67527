"""Fault injection: write failures. A file too large for the process (RLIMIT_FSIZE), a full disk and a
read-only file system (a small tmpfs), and a folder the user may not write: each is one clear error naming
the file and a fix, the manifest says `interrupted`, and `resume` after the fix completes identically."""

import contextlib
import json
import os
import shutil
import signal
import subprocess

import pandas as pd
import pytest
from faults_helpers import SMOKE, remount, rows, run_cli_child, small_disk, waveforms

from neatskin.datasets.curate import describe
from neatskin.errors import DataError
from neatskin.rig.runner import resume_campaign

pytestmark = pytest.mark.slow  # the fast lane, pytest -m 'not slow', leaves it out


@pytest.fixture
def reference(smoke_reference):
    return smoke_reference  # conftest: once per worker, for every module that reads it


RUN = ("campaign", "run", str(SMOKE), "--dry-run", "--quiet", "--no-report")


def _limit_file_size(limit_bytes):
    def apply():
        import resource

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG as an error, not the default kill
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return apply


def _assert_stopped_cleanly(done, folder, file_part, fix_part):
    assert done.returncode == 5, (done.returncode, done.stderr)
    assert "Traceback" not in done.stderr
    error = done.stderr.strip().splitlines()[-1]
    assert error.startswith("neatskin: error: ") and file_part in error and fix_part in error, error
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and file_part in manifest["stopped_by"]
    return manifest


@contextlib.contextmanager
def unwritable(folder):
    """`folder` made unwritable for the block: mode 555, or for root (who writes through any mode bits) immutable
    (chattr +i: EPERM); skipped where the file system has no immutable flag."""
    if os.geteuid() == 0:
        if subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode != 0:
            pytest.skip("chattr +i is not supported on this file system")
        undo = ["chattr", "-i", str(folder)]
    else:
        os.chmod(folder, 0o555)
        undo = ["chmod", "755", str(folder)]
    try:
        yield
    finally:
        subprocess.run(undo, check=True)


@pytest.mark.timeout(180)
def test_file_too_large_is_one_clear_error_then_resume_completes(reference, tmp_path):
    folder = tmp_path / "c"
    # a waveform part is about 880 kB: the first one exceeds 500 kB, the manifest and inputs fit
    done = run_cli_child("none", *RUN, "--out", str(folder), preexec_fn=_limit_file_size(500_000))
    _assert_stopped_cleanly(done, folder, "waveforms/position_id=", "ulimit -f")
    assert describe(folder)["status"] == "interrupted" and describe(folder)["presses"] == 0
    result = resume_campaign(folder, progress=False, report=False)
    assert result.completed == 12
    pd.testing.assert_frame_equal(rows(folder), rows(reference), check_exact=True)
    pd.testing.assert_frame_equal(waveforms(folder), waveforms(reference), check_exact=True)


@pytest.mark.timeout(180)
def test_full_disk_is_one_clear_error_then_resume_on_a_bigger_disk_completes(reference, tmp_path):
    with small_disk(tmp_path / "disk", "2m") as disk:
        folder = disk / "c"
        done = run_cli_child("none", *RUN, "--out", str(folder))
        manifest = _assert_stopped_cleanly(done, folder, str(disk), "disk is full")
        assert "No space left on device" in manifest["stopped_by"]
        assert not [p for p in folder.rglob("*.tmp")]  # no half-written temp file left behind
        remount(disk, "size=64m")  # the fix: more space
        result = resume_campaign(folder, progress=False, report=False)
        assert result.completed == 12 and result.written_now == 12 - manifest["counts"]["completed"]
        pd.testing.assert_frame_equal(rows(folder), rows(reference), check_exact=True)
        pd.testing.assert_frame_equal(waveforms(folder), waveforms(reference), check_exact=True)


@pytest.mark.timeout(180)
def test_resumed_fsr_waveform_is_bit_identical(reference, tmp_path):
    with small_disk(tmp_path / "disk", "2m") as disk:
        folder = disk / "c"
        run_cli_child("none", *RUN, "--out", str(folder))
        remount(disk, "size=64m")
        resume_campaign(folder, progress=False, report=False)
        pd.testing.assert_frame_equal(waveforms(folder), waveforms(reference), check_exact=True)


@pytest.mark.timeout(180)
def test_read_only_file_system_is_one_clear_error_then_resume_completes(reference, tmp_path):
    with small_disk(tmp_path / "disk", "64m") as disk:
        folder = disk / "c"
        done = run_cli_child("none", *RUN, "--out", str(folder), "--limit", "4")
        assert done.returncode == 0, done.stderr
        remount(disk, "ro")
        with pytest.raises(DataError) as err:
            resume_campaign(folder, progress=False, report=False)
        assert err.value.file == str(folder / "campaign.lock") and "read-only" in str(err.value)
        new = run_cli_child("none", *RUN, "--out", str(disk / "new"))
        assert new.returncode == 5 and "Traceback" not in new.stderr and "read-only" in new.stderr.lower()
        remount(disk, "rw")
        result = resume_campaign(folder, progress=False, report=False)
        assert (result.completed, result.written_now) == (12, 8)
        pd.testing.assert_frame_equal(rows(folder), rows(reference), check_exact=True)


@pytest.mark.timeout(180)
def test_a_folder_the_user_may_not_write_is_one_clear_error(reference, tmp_path):
    folder = tmp_path / "c"
    shutil.copytree(reference, folder)
    (folder / "presses.parquet").unlink()  # something for resume to do
    (folder / "campaign.lock").unlink()
    with unwritable(folder):
        done = run_cli_child("none", "campaign", "resume", str(folder), "--no-report", "--quiet")
    assert done.returncode == 5 and "Traceback" not in done.stderr, done.stderr
    assert str(folder / "campaign.lock") in done.stderr and "chmod u+w" in done.stderr
    assert "Permission denied" in done.stderr or "Operation not permitted" in done.stderr
    result = resume_campaign(folder, progress=False, report=False)  # after the fix
    assert result.completed == 12 and result.written_now == 0
    pd.testing.assert_frame_equal(rows(folder), rows(reference), check_exact=True)


@pytest.mark.timeout(180)
@pytest.mark.parametrize("where", ["presses", "waveforms"])
def test_resume_into_a_parts_folder_it_cannot_write_is_refused_before_any_motion(reference, tmp_path, where):
    """presses/ (or a waveforms/position_id=K/ of a campaign recording waveforms) refuses files: resume says so
    naming the folder and the fix before the rig is opened: the wire log gains not a byte (no G28, no press
    thrown away), the manifest is as it was; after the fix resume completes identically."""
    folder = tmp_path / "c"
    done = run_cli_child("none", *RUN, "--out", str(folder), "--limit", "5")
    assert done.returncode == 0 and "5/12 presses" in done.stdout, done.stderr
    locked = folder / "presses" if where == "presses" else sorted((folder / "waveforms").glob("position_id=*"))[0]
    wire_before = (folder / "wire.log").read_bytes()
    manifest_before = json.loads((folder / "manifest.json").read_text())
    with unwritable(locked):
        refused = run_cli_child("none", "campaign", "resume", str(folder), "--no-report", "--quiet")
    assert (folder / "wire.log").read_bytes() == wire_before, refused.stderr  # not a byte to the printer
    assert refused.returncode == 5 and "Traceback" not in refused.stderr, refused.stderr
    what = "presses" if where == "presses" else "waveforms"
    assert refused.stderr.startswith(
        f"neatskin: error: {locked}: cannot write in this folder, where the {what} go: "
    ), refused.stderr
    assert "nothing was sent to the printer (fix: give your user write permission" in refused.stderr
    assert len(refused.stderr.splitlines()) == 1
    manifest = json.loads((folder / "manifest.json").read_text())
    assert (manifest["status"], manifest["counts"]) == (manifest_before["status"], manifest_before["counts"])
    assert not list(folder.rglob(".write-probe*"))  # the probe leaves nothing behind
    result = resume_campaign(folder, progress=False, report=False)  # after the fix
    assert (result.completed, result.written_now) == (12, 7)
    pd.testing.assert_frame_equal(rows(folder), rows(reference), check_exact=True)
    pd.testing.assert_frame_equal(waveforms(folder), waveforms(reference), check_exact=True)
