"""What an OSError means for the user and how to fix it: the one errno table behind every path, read and write error.

The same errno asks for a different fix depending on what the toolkit was doing with the path, so each entry has
one cause (what the errno means, said once) and a remedy per doing:

- "use": a path the command was given, read or written unknown (the CLI's last resort for an OSError no check named);
- "read": a file that exists but cannot be read (a manifest, a press file);
- "write": a file written into a folder (a campaign's part, an export);
- "find": a path another file names, looked up before it is read (a protocol's [files] entries).

A doing with no remedy of its own falls back to "use" ("find" to its default, which names the file it wants); an
errno with no entry gets the doing's default. A new errno is added here once, and every error above reads it. Remedies hold placeholders the
caller fills: {then} (what to do after the fix: "then resume", "then run the command again"), {path} and {what}.
"""

from __future__ import annotations

import errno
import os
import re
from dataclasses import dataclass
from typing import Literal

from neatskin.errors import DataError

Doing = Literal["use", "read", "write", "find"]

THEN = {
    "use": "then run the command again",
    "read": "then restore the file from a backup",
    "write": "then resume",
    "find": "then run the command again",
}
# Where a doing with no remedy of its own looks next; "find" has a default of its own (name the file it wants).
_FALLBACK = {"use": ("use",), "read": ("read", "use"), "write": ("write", "use"), "find": ("find",)}


@dataclass(frozen=True)
class Meaning:
    """One errno for the user: what it means (None: the system's own reason says it all) and the fix per doing."""

    cause: str | None
    use: str
    read: str | None = None
    write: str | None = None
    find: str | None = None

    def remedy(self, doing: Doing) -> str | None:
        return next((text for name in _FALLBACK[doing] if (text := getattr(self, name)) is not None), None)


_PERMISSION = Meaning(
    None,
    use="choose a path you may use (-o/--out for an output), or give your user permission on it",
    read="give your user read permission on it (chmod u+r {path})",
    write="give your user write permission on the folder (chmod u+w), {then}",
    find="give your user read permission on the file and search (x) permission on each folder of its path",
)

MEANINGS: dict[int, Meaning] = {
    errno.ENOENT: Meaning(None, use="check that the path and the folders above it exist"),
    errno.EACCES: _PERMISSION,
    errno.EPERM: _PERMISSION,
    errno.EROFS: Meaning(
        "the file system is read-only",
        use="choose a folder on a writable disk",
        write="remount it read-write or copy the campaign to a writable disk, {then}",
    ),
    errno.ENOSPC: Meaning(
        "the disk is full",
        use="free space on it, {then}",
        write="free space on it (or move the campaign to a bigger disk), {then}",
    ),
    errno.EDQUOT: Meaning("your disk quota is used up", use="free space or raise the quota, {then}"),
    errno.EFBIG: Meaning(
        "the file is larger than this process may write (ulimit -f) or than the file system allows",
        use="raise the limit (ulimit -f unlimited) or use another disk, {then}",
    ),
    errno.EIO: Meaning(
        "the disk reported an I/O error",
        use="check it (dmesg), {then}",
        write="check it (dmesg), copy the campaign elsewhere, {then}",
    ),
    errno.ENAMETOOLONG: Meaning(None, use="give a shorter path", find="give a shorter path to an existing {what}"),
    errno.ELOOP: Meaning(
        "the path runs through a loop of symbolic links",
        use="correct or remove the link",
        read="remove the link, {then}",
        find="point it at the {what} itself",
    ),
    errno.ENOTDIR: Meaning("a part of the path is a file, not a folder", use="correct the path"),
    errno.EISDIR: Meaning(
        "a folder stands where the file should be",
        use="give the path of a file, not a folder",
        read="move the folder away, {then}",
    ),
    errno.EEXIST: Meaning("that path exists already", use="choose another one or remove it"),
}

DEFAULT_FIX = {
    "use": "check the path, the disk and the permissions, {then}",
    "read": "check the disk (dmesg), {then}",
    "write": "check the disk and the folder's permissions, {then}",
    "find": "give the path of an existing, readable {what}",
}

_WHAT_FAILED = {"use": "cannot use the path", "read": "cannot read the file", "write": "cannot write the file"}


def errno_of(exc: BaseException) -> int | None:
    """The errno of an OSError; of an exception without one whose text carries one this table knows (pyarrow raises
    errno-less errors with the OS error in its message: '[errno 28] No space left on device'), that one; else None."""
    code = getattr(exc, "errno", None)
    if isinstance(code, int):
        return code
    text = str(exc)
    number = re.search(r"errno (\d+)", text, re.IGNORECASE)  # whole: 'errno 2' is not in 'errno 28'
    if number:
        return int(number.group(1))
    return next((c for c in MEANINGS if os.strerror(c) in text), None)


def fix_for(code: int | None, doing: Doing, *, then: str | None = None, path: object = "", what: str = "file") -> str:
    """The fix for errno `code` met while `doing` a path: the cause, then the remedy, placeholders filled."""
    meaning = MEANINGS.get(code) if code is not None else None
    remedy = (meaning.remedy(doing) if meaning else None) or DEFAULT_FIX[doing]
    text = f"{meaning.cause}: {remedy}" if meaning and meaning.cause else remedy
    return text.format(then=THEN.get(doing, "") if then is None else then, path=path, what=what)


def os_error(exc: BaseException, doing: Doing, path: object | None = None, *, then: str | None = None) -> DataError:
    """One clear DataError for `exc` met while `doing` `path` (the exception's own filename when None): the file,
    what failed with the system's reason, and the fix."""
    code = errno_of(exc)
    reason = getattr(exc, "strerror", None) or (
        os.strerror(code) if code is not None else str(exc) or type(exc).__name__
    )
    if path is None:
        path = getattr(exc, "filename", None)
    return DataError(
        f"{_WHAT_FAILED[doing if doing != 'find' else 'read']}: {reason}",
        file=None if path is None else str(path),
        fix=fix_for(code, doing, then=then, path=path or ""),
    )
