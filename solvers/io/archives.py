"""What a zip may hold before any of it is read: a member facecap can decompress, no larger than what it stands for.

A zip from elsewhere (the ICT-FaceKit download, an ``.npz``) is looked at through its central directory first, so a
member that would be read is refused before a byte of it is decompressed when it is

* encrypted, or compressed with a method Python's ``zipfile`` cannot read (Deflate64 and AES, which some zip tools
  write; implode, ...): named with the method, as a download to get again, not an internal error;
* larger than its limit (``zipfile`` never gives more than a member's recorded size, so the recorded size bounds
  what reading it costs);
* compressed more than ``max_ratio`` times (a zip bomb: 300 MB of repeated lines in 600 KB).

``check_members`` raises ``InputFileError`` naming the archive and the member.
"""

import zipfile

from ..errors import InputFileError

#: Compression methods ``zipfile`` reads: stored, deflate, bzip2, lzma
READABLE = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "Deflate", zipfile.ZIP_BZIP2: "bzip2",
            zipfile.ZIP_LZMA: "LZMA"}
#: Names of the methods it does not (PKWARE's APPNOTE 4.4.5)
UNREADABLE = {1: "Shrink", 6: "Implode", 9: "Deflate64", 10: "PKWARE DCL Implode", 18: "IBM TERSE", 19: "IBM LZ77",
              93: "Zstandard", 95: "xz", 96: "JPEG", 97: "WavPack", 98: "PPMd", 99: "AES encryption"}
#: Members smaller than this are not judged by their compression ratio (a small run of zeros compresses well)
RATIO_FLOOR = 1 << 16


def check_members(path, members, *, max_bytes, max_ratio, what, total=None):
    """Raise InputFileError unless every ``zipfile.ZipInfo`` of ``members`` can be read safely.

    path : the archive, for the message
    max_bytes : largest uncompressed size of one member (an int, or a callable of the ZipInfo)
    max_ratio : largest uncompressed / compressed size of a member above ``RATIO_FLOOR`` bytes
    what : what to do about it, ending the message ("download it again from ...")
    total : largest uncompressed size of all ``members`` together (None: no limit)
    """
    size = 0
    for info in members:
        name = info.filename
        if info.flag_bits & 0x1:
            raise InputFileError(path, f"{name} is encrypted (a password-protected zip); {what}")
        if info.compress_type not in READABLE:
            method = UNREADABLE.get(info.compress_type, f"method {info.compress_type}")
            raise InputFileError(path, f"{name} is compressed with {method} (zip method {info.compress_type}), which "
                                       f"facecap cannot read; {what}")
        limit = max_bytes(info) if callable(max_bytes) else max_bytes
        if info.file_size > limit:
            raise InputFileError(path, f"{name} is {_mb(info.file_size)} unpacked; at most {_mb(limit)} is expected "
                                       f"there; {what}")
        if info.file_size > RATIO_FLOOR and info.file_size > max_ratio * max(info.compress_size, 1):
            raise InputFileError(path, f"{name} unpacks {info.file_size / max(info.compress_size, 1):.0f} times its "
                                       f"packed size (a zip bomb?; at most {max_ratio} times is expected); {what}")
        size += info.file_size
    if total is not None and size > total:
        raise InputFileError(path, f"the files read unpack to {_mb(size)}; at most {_mb(total)} is expected; {what}")
    return size


def _mb(n):
    return f"{n / 2**20:.1f} MiB" if n >= 2**20 else f"{n} bytes"
