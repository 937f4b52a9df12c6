"""Replacing a file's text all at once: a kill or a crash leaves the old text or the new, never half.

Used for the files a user asks for (`export`, `save`) and for a running solve's checkpoint
(midsolve.py), which is replaced every few seconds while a kill may come at any moment.
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path


def replace_text(path: Path, text: str, *, overwrite: bool = True) -> None:
    """Write ``text`` (UTF-8, newlines as given) to a temporary file beside ``path``, fsync it,
    rename it over ``path`` and fsync the folder, so that the rename survives a crash too. The file
    gets the mode a new file gets under the user's umask (not the temporary file's 0600).

    Args:
        overwrite: replace a regular file at ``path``; without it, an existing one is refused
            (the temporary file is linked in place, which fails if ``path`` exists, so nothing
            can appear there between a check and the write). Never anything else at ``path``:
            a rename replaces a symlink itself, never its target, and is refused here anyway.
    Raises:
        FileExistsError: ``path`` exists (anything at all, without ``overwrite``; with it, what
            is not a regular file).
        OSError: the file cannot be written (no temporary file is left behind).
    """
    if path.is_symlink() or (path.exists() and not path.is_file()):
        raise FileExistsError(errno.EEXIST, "it is not a regular file (a link, a folder or a device)")
    fd, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as out:
            out.write(text)
            out.flush()
            os.fsync(out.fileno())
        if overwrite:
            os.replace(temporary, path)
        else:
            os.link(temporary, path)   # FileExistsError if anything is there by now
            os.unlink(temporary)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    _sync_folder(path.parent)


def _umask() -> int:
    mask = os.umask(0o022)   # the only way to read it is to set it: put it straight back
    os.umask(mask)
    return mask


def _sync_folder(folder: Path) -> None:
    """fsync a folder, so that a rename in it survives a crash (where the system allows it)."""
    try:
        handle = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(handle)
    except OSError:
        pass
    finally:
        os.close(handle)
