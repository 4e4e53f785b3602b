"""Where an output file goes, checked before any work and again when it is written.

Every output of the command line (``-o``, ``--plot``; ``verify --out`` is a folder,
:func:`ftc_verify.verification.report.check_out_dir`) is written to a temporary file in
the target's folder and renamed over the target (:func:`os.replace`), so a failure never
leaves a half-written file. A rename replaces whatever the name points at, so the rule
for an existing target is decided here, once, for every writer:

* a regular file is replaced (atomically);
* a symbolic link is followed (:func:`os.path.realpath`, links of links included) and the
  file it points to is replaced, as the shell's ``>`` and ``cp`` write through a link:
  the link is the user's name for that file, and replacing the link by a regular file
  would silently detach it and leave its target stale (a dangling link creates its
  target, as ``>`` does);
* anything else -- a FIFO, a character or block device (``/dev/null``), a socket, a
  folder -- is refused with the option, the path and what it is (exit 2): renaming a file
  over it would destroy the node (as root, ``-o /dev/null`` would replace the machine's
  ``/dev/null``), and writing into it instead would not be the atomic, complete file the
  command promises.

A name the operating system cannot use -- a link that points back to itself (a loop,
``ELOOP``), a name longer than the file system allows (``ENAMETOOLONG``) -- is refused the
same way, with the option, the path and the OS's reason (:func:`check_name`).

The folder that receives the file must exist and accept a new file: :func:`probe_folder`
creates and removes a temporary file there, an actual write (an access test alone is
passed by root on ``/proc`` or ``/sys``, where the write itself then fails after the work).
"""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from pathlib import Path

from ..errors import ValidationError

__all__ = ["check_name", "kind_of", "output_target", "probe_folder"]

_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a folder"))


def kind_of(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words ("a FIFO", "a character device", ...)."""
    for test, words in _KINDS:
        if test(mode):
            return words
    return "a regular file" if stat.S_ISREG(mode) else "not a regular file"


def check_name(path: str | os.PathLike[str], label: str) -> None:
    """``path`` is a name the operating system can resolve, whether or not the file exists.

    Raises
    ------
    ValidationError
        Resolving ``path`` fails for another reason than a missing file or folder: a
        symbolic link loop (``ELOOP``), a name too long (``ENAMETOOLONG``), a folder of the
        path that cannot be searched; the message starts with ``label`` and gives the OS's
        reason.
    """
    try:
        os.stat(path)
    except (FileNotFoundError, NotADirectoryError):  # a new file; a file as a folder: the folder check says so
        return
    except OSError as exc:
        code = errno.errorcode.get(exc.errno or 0, "OSError")
        raise ValidationError(f"{label}: {exc.strerror or exc} ({code}); give another name") from None


def output_target(path: str | os.PathLike[str], label: str) -> Path:
    """The file an output named ``path`` replaces: ``path`` itself, or the file a symbolic
    link at ``path`` points to (module docstring).

    Raises
    ------
    ValidationError
        The target exists and is not a regular file; the message starts with ``label``
        (the option and the path, or the path) and says what it is (for a link, also the
        file it points to). Or ``path`` cannot be resolved (:func:`check_name`).
    """
    check_name(path, label)
    target = Path(os.path.realpath(path))
    try:
        mode = os.stat(target).st_mode
    except FileNotFoundError:
        return target
    except NotADirectoryError:  # a file where a folder of the path should be: the folder check says so
        return target
    if not stat.S_ISREG(mode):
        via = f" (the link points to {target})" if os.path.islink(path) else ""
        raise ValidationError(f"{label}: is {kind_of(mode)}{via}, not a regular file; "
                              "an output is written to a new file renamed over the target, which would destroy it "
                              "(name a regular file or a new one)")
    return target


def probe_folder(folder: Path, message: str) -> None:
    """Create and remove a temporary file in ``folder``: the folder exists and accepts a
    new file (module docstring), else :class:`ValidationError` of ``message``, the
    folder's state and the OS's reason."""
    if not folder.exists():
        raise ValidationError(f"{message}: folder {folder} does not exist")
    if not folder.is_dir():
        raise ValidationError(f"{message}: {folder} is {kind_of(folder.stat().st_mode)}, not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".ftc-verify-probe.", dir=folder)
    except OSError as exc:
        raise ValidationError(f"{message}: folder {folder} is not writable ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)
