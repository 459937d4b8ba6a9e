"""A look at a .blend file's structure without Blender: is it whole?

Blender reads a damaged .blend badly: a truncated file ends in ``RuntimeError: ... Missing DNA
block``, some damaged ones crash the process. ``check_blend_structure`` catches what can be seen from
the outside, cheaply and before Blender parses anything: a file that is not a .blend, and a file cut
short (half copied, a full disk):

* uncompressed: the header, then every block header in turn, each block inside the file, up to the
  ``ENDB`` block, with the ``DNA1`` block on the way (the blocks' contents are skipped, not read);
* zstd (Blender's ``compress``): the seekable format's seek table at the end, whose frames must add
  up to the file's size;
* gzip (Blender before 3.0): the gzip header.

Damage inside a block's contents cannot be seen this way; the Blender layer opens a file in a forked
child first where it can (``facecap_addon.headless.blend_files``).
"""

import os
import struct

from ..errors import InputFileError
from .limits import check_input_file

#: Largest .blend opened (bytes): far beyond any character with its takes; a file this size is not one
MAX_BLEND_BYTES = 1 << 40

ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
GZIP_MAGIC = b"\x1f\x8b"
_SEEKABLE_MAGIC = 0x8F92EAB1
_SKIPPABLE_SEEK_TABLE = 0x184D2A5E


def check_blend_structure(path, what=""):
    """Raise InputFileError naming ``path`` (and ``what`` it is for, e.g. "[target] blend") unless it
    looks like a whole .blend file."""
    size = check_input_file(path, limit=MAX_BLEND_BYTES)
    try:
        with open(path, "rb") as fh:
            head = fh.read(32)
            if head.startswith(ZSTD_MAGIC):
                problem = _zstd_problem(fh, size)
            elif head.startswith(GZIP_MAGIC):
                problem = None if len(head) >= 10 and head[2] == 8 else "a damaged gzip header"
            elif head.startswith(b"BLENDER"):
                problem = _blocks_problem(fh, head, size)
            else:
                problem = "does not start like one"
    except OSError as exc:
        raise InputFileError(path, f"cannot be read ({exc.strerror or exc})") from None
    if problem is not None:
        raise InputFileError(path, f"not a .blend file Blender can read{f' ({what})' if what else ''}: {problem}")


def _header(head):
    """(header length, block header format, its field order) of an uncompressed .blend, or None."""
    if head[7:9] == b"17" and head[9:10] == b"-" and head[12:13] in (b"v", b"V"):  # Blender 5.0+ (large blocks)
        end = "<" if head[12:13] == b"v" else ">"
        return 17, end + "4sIQqq", ("code", "sdna", "old", "len", "nr")
    pointer, endian = head[7:8], head[8:9]
    if pointer not in (b"_", b"-") or endian not in (b"v", b"V") or not head[9:12].isdigit():
        return None
    end = "<" if endian == b"v" else ">"
    fmt = end + ("4siQii" if pointer == b"-" else "4siIii")
    return 12, fmt, ("code", "len", "old", "sdna", "nr")


def _blocks_problem(fh, head, size):
    layout = _header(head)
    if layout is None:
        return "an unknown header"
    offset, fmt, order = layout
    step = struct.calcsize(fmt)
    seen_dna = False
    blocks = 0
    while True:
        if offset + step > size:
            return f"cut short after {blocks} blocks (at byte {offset} of {size}; no end block)"
        fh.seek(offset)
        fields = dict(zip(order, struct.unpack(fmt, fh.read(step))))
        if fields["code"] == b"ENDB":
            break
        length = fields["len"]
        if length < 0 or offset + step + length > size:
            return f"block {blocks + 1} ({fields['code']!r}) runs past the end of the file (byte {size})"
        seen_dna |= fields["code"] == b"DNA1"
        offset += step + length
        blocks += 1
    return None if seen_dna else "no DNA block"


def _zstd_problem(fh, size):
    """Blender writes zstd in the seekable format: frames, then a seek table listing their sizes."""
    if size < 17:
        return "cut short (a few bytes of zstd data)"
    fh.seek(size - 9)
    frames, descriptor, magic = struct.unpack("<IBI", fh.read(9))
    if magic != _SEEKABLE_MAGIC:
        return "cut short or damaged (the zstd seek table at its end is missing)"
    entry = 12 if descriptor & 0x80 else 8
    table = 8 + frames * entry + 9
    if table > size:
        return "damaged zstd seek table"
    fh.seek(size - table)
    skippable, table_size = struct.unpack("<II", fh.read(8))
    if skippable != _SKIPPABLE_SEEK_TABLE or table_size != frames * entry + 9:
        return "damaged zstd seek table"
    entries = fh.read(frames * entry)
    compressed = sum(struct.unpack_from("<I", entries, i * entry)[0] for i in range(frames))
    if compressed + table != size:
        return f"its zstd frames add up to {compressed + table} bytes, the file has {size}"
    return None
