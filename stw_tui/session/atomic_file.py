"""Replacing a file's text all at once: a kill or a crash leaves the old text or the new, never half.

Used for the files a user asks for (`export`, `save`) and for a running solve's checkpoint
(midsolve.py), which is replaced every few seconds while a kill may come at any moment.
"""

from __future__ import annotations

import errno
import os
import secrets
import tempfile
from pathlib import Path


def replace_text(path: Path, text: str, *, overwrite: bool = True) -> None:
    """Write ``text`` (UTF-8, newlines as given) to a temporary file beside ``path``, fsync it,
    rename it over ``path`` and fsync the folder, so that the rename survives a crash too. The file
    gets the mode any new file gets under the user's umask (0644 under 022, 0600 under 077).

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
    fd, temporary = _new_temporary(path)
    try:
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


def _new_temporary(path: Path) -> tuple[int, str]:
    """A new, empty temporary file beside ``path``: (descriptor open for writing, its name).

    Made like any new file, with mode 0666 less the umask, which the system applies. (mkstemp makes
    0600, and reading the umask to widen that means setting it, process-wide, for a moment: a file
    another thread creates meanwhile, such as a journal line's or the theme's, gets the wrong mode.)
    """
    for _ in range(tempfile.TMP_MAX):
        name = str(path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp")
        try:
            return os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o666), name
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, f"no free temporary name beside {path.name}")


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
