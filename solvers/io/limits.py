"""What a reader accepts before it reads a byte: a regular file, no larger than its limit.

A FIFO or a device given as a take would block a reader forever or feed it without end (``/dev/zero``
fills the memory); a file larger than any take is a mistake (the wrong file) or damage. Both are
refused with one line naming the file. The limits (bytes):

* ``MAX_CAPTURE_BYTES`` (16 GiB): marker and weights files (C3D, TRC, CSV, JSON). A 360,000-frame take
  of 53 markers is about 0.6 GB as CSV, so the limit leaves room for some 10 hours at 60 fps.
* ``MAX_TEXT_BYTES`` (256 MiB): small text inputs: configs, binding maps, corrections, seed points,
  presets.
"""

import os
import stat

from ..errors import InputFileError

MAX_CAPTURE_BYTES = 16 << 30
MAX_TEXT_BYTES = 256 << 20


def file_kind(mode):
    """What a file of ``st_mode`` is, in words, when it is not a regular file."""
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_input_file(path, *, limit=MAX_CAPTURE_BYTES, missing="file not found"):
    """Raise InputFileError unless ``path`` is a regular file of at most ``limit`` bytes; returns its size."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputFileError(path, missing) from None
    except (OSError, ValueError) as exc:
        raise InputFileError(path, f"cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(path, f"is {file_kind(st.st_mode)}; facecap reads only regular files")
    if st.st_size > limit:
        raise InputFileError(path, f"is {st.st_size / 2**30:.1f} GiB; facecap reads files of at most "
                                   f"{limit / 2**30:g} GiB of this kind (the wrong file?)")
    return st.st_size
