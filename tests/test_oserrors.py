"""The one errno -> fix table (neatskin.oserrors) through each of its four entry points: the CLI's last resort
(cli.path_error), a campaign file that cannot be read or written (datasets.durable.read_error / write_error) and a
protocol's [files] path (rig.protocol._path_fix). Each errno gives one DataError naming the file, the system's
reason and the fix users saw before the table was shared; real system calls give the same errors as built ones."""

from __future__ import annotations

import argparse
import errno
import os
from pathlib import Path

import pytest

import neatskin.cli as cli
from neatskin.datasets.durable import read_error, then_instead_of_resume, write_bytes_durably, write_error
from neatskin.errors import DataError
from neatskin.oserrors import DEFAULT_FIX, MEANINGS, errno_of, fix_for, os_error
from neatskin.rig.protocol import _path_fix

PATH = "/data/campaign/part-000003.parquet"
RESTORE = "restore manifest.json from a backup (the presses are not in it and stay as they are)"
PERMISSION_USE = "choose a path you may use (-o/--out for an output), or give your user permission on it"

# The texts of the four tables before they were one, per errno (None: the entry point had no entry and gave its
# default). Harmonised on purpose, and so different here: the read ELOOP said "the name is a link that leads back to
# itself", the protocol's "the path is a loop of symbolic links" (now both "the path runs through a loop of symbolic
# links", the CLI's words); the CLI's EISDIR now says the cause as the read one does.
USE = {
    errno.ENOENT: "check that the path and the folders above it exist",
    errno.EACCES: PERMISSION_USE,
    errno.EPERM: PERMISSION_USE,
    errno.EROFS: "the file system is read-only: choose a folder on a writable disk",
    errno.ENOSPC: "the disk is full: free space on it, then run the command again",
    errno.EDQUOT: "your disk quota is used up: free space or raise the quota, then run the command again",
    errno.EFBIG: "the file is larger than this process may write (ulimit -f) or than the file system allows: "
    "raise the limit (ulimit -f unlimited) or use another disk, then run the command again",
    errno.EIO: "the disk reported an I/O error: check it (dmesg), then run the command again",
    errno.ENAMETOOLONG: "give a shorter path",
    errno.ELOOP: "the path runs through a loop of symbolic links: correct or remove the link",
    errno.ENOTDIR: "a part of the path is a file, not a folder: correct the path",
    errno.EISDIR: "a folder stands where the file should be: give the path of a file, not a folder",
    errno.EEXIST: "that path exists already: choose another one or remove it",
}
WRITE = {
    errno.ENOSPC: "the disk is full: free space on it (or move the campaign to a bigger disk), then resume",
    errno.EDQUOT: "your disk quota is used up: free space or raise the quota, then resume",
    errno.EFBIG: "the file is larger than this process may write (ulimit -f) or than the file system allows: "
    "raise the limit (ulimit -f unlimited) or use another disk, then resume",
    errno.EACCES: "give your user write permission on the folder (chmod u+w), then resume",
    errno.EPERM: "give your user write permission on the folder (chmod u+w), then resume",
    errno.EROFS: "the file system is read-only: remount it read-write or copy the campaign to a writable disk, "
    "then resume",
    errno.EIO: "the disk reported an I/O error: check it (dmesg), copy the campaign elsewhere, then resume",
}
READ = {
    errno.EACCES: f"give your user read permission on it (chmod u+r {PATH})",
    errno.EPERM: f"give your user read permission on it (chmod u+r {PATH})",
    errno.EISDIR: f"a folder stands where the file should be: move the folder away, then {RESTORE}",
    errno.ELOOP: f"the path runs through a loop of symbolic links: remove the link, then {RESTORE}",
    errno.EIO: f"the disk reported an I/O error: check it (dmesg), then {RESTORE}",
}
FIND = {
    errno.EACCES: "give your user read permission on the file and search (x) permission on each folder of its path",
    errno.EPERM: "give your user read permission on the file and search (x) permission on each folder of its path",
    errno.ELOOP: "the path runs through a loop of symbolic links: point it at the TOML file itself",
    errno.ENAMETOOLONG: "give a shorter path to an existing TOML file",
}
ALL_CODES = sorted(MEANINGS)


def _oserror(code: int) -> OSError:
    return OSError(code, os.strerror(code), PATH)


def _only_problem(error: DataError):
    assert isinstance(error, DataError) and len(error.problems) == 1
    return error.problems[0]


def test_the_table_covers_every_errno_the_four_tables_did():
    assert set(USE) | set(WRITE) | set(READ) | set(FIND) <= set(MEANINGS)
    assert len(MEANINGS) == len(ALL_CODES) == 13


@pytest.mark.parametrize("code", ALL_CODES, ids=errno.errorcode.get)
def test_the_cli_gives_one_error_per_errno_with_the_path_reason_and_fix(code, capsys, monkeypatch):
    """Through main(): exit 5, one line: the path, 'cannot use the path', the system's reason, the table's fix."""

    def handler(args):
        raise _oserror(code)

    parser = argparse.ArgumentParser()
    parser.set_defaults(handler=handler)
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    assert cli.main([]) == 5
    assert capsys.readouterr().err == (
        f"neatskin: error: {PATH}: cannot use the path: {os.strerror(code)} (fix: {USE[code]})\n"
    )


@pytest.mark.parametrize("code", ALL_CODES, ids=errno.errorcode.get)
def test_a_write_gives_one_error_per_errno_and_an_export_swaps_its_then(code):
    problem = _only_problem(write_error(_oserror(code), PATH))
    assert (problem.file, problem.message) == (PATH, f"cannot write the file: {os.strerror(code)}")
    assert problem.fix == WRITE.get(code, USE[code].replace("then run the command again", "then resume"))
    exported = _only_problem(then_instead_of_resume(write_error(_oserror(code), PATH), "then run the command again"))
    assert "resume" not in exported.fix and exported.fix == problem.fix.replace(
        "then resume", "then run the command again"
    )


@pytest.mark.parametrize("code", ALL_CODES, ids=errno.errorcode.get)
def test_a_read_gives_one_error_per_errno_ending_with_how_to_restore_the_file(code):
    problem = _only_problem(read_error(_oserror(code), PATH, RESTORE))
    assert (problem.file, problem.message) == (PATH, f"cannot read the file: {os.strerror(code)}")
    assert problem.fix == READ.get(code, USE[code].replace("then run the command again", f"then {RESTORE}"))


@pytest.mark.parametrize("code", ALL_CODES, ids=errno.errorcode.get)
def test_a_protocol_files_path_gets_its_fix_or_the_toml_default_with_the_cause(code):
    cause = MEANINGS[code].cause
    default = "give the path of an existing, readable TOML file"
    assert _path_fix(_oserror(code)) == FIND.get(code, f"{cause}: {default}" if cause else default)


def test_python_3_11s_loop_of_links_runtime_error_is_a_loop_for_the_protocol():
    assert _path_fix(RuntimeError("Symlink loop from '/p/loop.toml'")) == FIND[errno.ELOOP]


def test_an_errno_the_table_does_not_know_gets_each_doings_default():
    code = errno.EXDEV  # cross-device link: no entry
    assert code not in MEANINGS
    assert fix_for(code, "use") == "check the path, the disk and the permissions, then run the command again"
    assert fix_for(code, "write") == "check the disk and the folder's permissions, then resume"
    assert fix_for(code, "read", then=f"then {RESTORE}") == f"check the disk (dmesg), then {RESTORE}"
    assert fix_for(code, "find", what="TOML file") == DEFAULT_FIX["find"].format(what="TOML file")


def test_pyarrows_errno_less_error_is_read_from_its_text():
    """pyarrow raises OSErrors without an errno, the OS error in the text: the table still finds the disk full."""
    exc = OSError("Error writing bytes to file. Detail: [errno 28] No space left on device")
    assert exc.errno is None and errno_of(exc) == errno.ENOSPC
    problem = _only_problem(write_error(exc, PATH))
    assert problem.message == "cannot write the file: No space left on device" and problem.fix == WRITE[errno.ENOSPC]
    assert errno_of(ValueError("no errno here")) is None


# Real system calls: the errors the OS raises, not built ones, through the entry points.


def _real_oserror(tmp_path: Path, code: int) -> tuple[OSError, Path]:
    """Provoke `code` with a real system call under tmp_path; the error and the path it names."""
    if code == errno.ENOENT:
        path = tmp_path / "missing" / "file"
        call = path.read_bytes
    elif code == errno.ENOTDIR:
        (tmp_path / "a-file").write_text("x")
        path = tmp_path / "a-file" / "inside"
        call = path.read_bytes
    elif code == errno.EISDIR:
        path = tmp_path / "a-folder"
        path.mkdir()
        call = path.read_bytes
    elif code == errno.ELOOP:
        path = tmp_path / "loop"
        path.symlink_to("loop")
        call = path.read_bytes
    elif code == errno.ENAMETOOLONG:
        path = tmp_path / ("x" * 300)
        call = path.read_bytes
    else:
        path = tmp_path / "exists"
        path.write_text("x")
        call = lambda: os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)  # noqa: E731
    with pytest.raises(OSError) as raised:
        call()
    assert raised.value.errno == code
    return raised.value, path


REAL = [errno.ENOENT, errno.ENOTDIR, errno.EISDIR, errno.ELOOP, errno.ENAMETOOLONG, errno.EEXIST]


@pytest.mark.parametrize("code", REAL, ids=errno.errorcode.get)
def test_a_real_os_error_through_the_cli_names_its_path_and_the_fix(code, tmp_path, capsys, monkeypatch):
    exc, path = _real_oserror(tmp_path, code)

    def handler(args):
        raise exc

    parser = argparse.ArgumentParser()
    parser.set_defaults(handler=handler)
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    assert cli.main([]) == 5
    err = capsys.readouterr().err
    assert err == f"neatskin: error: {path}: cannot use the path: {os.strerror(code)} (fix: {USE[code]})\n"


@pytest.mark.parametrize("code", [errno.ENOENT, errno.ENOTDIR, errno.ENAMETOOLONG], ids=errno.errorcode.get)
def test_a_real_durable_write_that_fails_is_one_error_and_leaves_no_file(code, tmp_path):
    """write_bytes_durably into a missing folder, under a file, or with a name too long: one DataError naming the
    target, the use fix (these errnos have no write-specific one), and nothing left behind."""
    (tmp_path / "a-file").write_text("x")
    target = {
        errno.ENOENT: tmp_path / "missing" / "out.bin",
        errno.ENOTDIR: tmp_path / "a-file" / "out.bin",
        errno.ENAMETOOLONG: tmp_path / ("x" * 300),
    }[code]
    with pytest.raises(DataError) as raised:
        write_bytes_durably(target, b"data")
    problem = _only_problem(raised.value)
    assert problem.file == str(target) and problem.message == f"cannot write the file: {os.strerror(code)}"
    assert problem.fix == USE[code]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]


@pytest.mark.parametrize("code", [errno.EISDIR, errno.ELOOP], ids=errno.errorcode.get)
def test_a_real_unreadable_manifest_names_it_and_how_to_restore_it(code, tmp_path):
    from neatskin.datasets.manifest import read_manifest

    folder = tmp_path / "campaign"
    folder.mkdir()
    manifest = folder / "manifest.json"
    if code == errno.EISDIR:
        manifest.mkdir()
    else:
        manifest.symlink_to("manifest.json")
    with pytest.raises(DataError) as raised:
        read_manifest(folder)
    problem = _only_problem(raised.value)
    assert problem.file == str(manifest) and problem.message == f"cannot read the file: {os.strerror(code)}"
    assert problem.fix == READ[code]


def test_os_error_without_a_path_names_the_exceptions_own_file():
    problem = _only_problem(os_error(OSError(errno.ENOSPC, "No space left on device", "/x/y"), "use"))
    assert problem.file == "/x/y" and problem.fix == USE[errno.ENOSPC]
    assert _only_problem(os_error(OSError(errno.ENOSPC, "No space left on device"), "use")).file is None


def test_a_name_the_file_system_takes_is_written_though_its_temp_files_name_is_longer(tmp_path):
    """255 bytes is the longest name; the temp file (`.NAME.<random>.tmp`, 14 more) is cut short, not refused."""
    target = tmp_path / ("é" * 100 + "x" * 55)  # 255 bytes in UTF-8
    assert len(target.name.encode()) == 255
    write_bytes_durably(target, b"data")
    assert target.read_bytes() == b"data" and sorted(tmp_path.iterdir()) == [target]
    with pytest.raises(DataError) as raised:  # one byte more: the file system's own refusal, one clear error
        write_bytes_durably(tmp_path / ("x" * 256), b"data")
    assert _only_problem(raised.value).fix == "give a shorter path"
