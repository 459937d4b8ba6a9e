"""A batch worker's kept characters: handed out as copies, sampled again when the .blend changes."""

import os

import numpy as np

from facecap.facecap_addon.batch.batch_worker import CharacterCache
from facecap.solvers.character.basis import Basis


def basis():
    rng = np.random.default_rng(0)
    return Basis(neutral=rng.normal(size=(4, 3)), deltas=rng.normal(size=(2, 4, 3)), shape_names=("a", "b"),
                 marker_names=("m0", "m1", "m2", "m3"))


def test_kept_characters_are_copies_and_follow_their_file(tmp_path):
    blend = tmp_path / "character.blend"
    blend.write_bytes(b"BLENDER-v500")
    calls = []

    def sample():
        calls.append(1)
        return basis()

    cache = CharacterCache(size=2)
    first = cache.get(blend, "Face", ("m0", "m1"), sample)
    first.deltas[:] = 0.0  # what one take does to its copy
    second = cache.get(blend, "Face", ("m0", "m1"), sample)
    assert len(calls) == 1 and cache.hits == 1
    np.testing.assert_array_equal(second.deltas, basis().deltas)  # the next take gets it untouched
    cache.get(blend, "Face", ("m0",), sample)  # other markers bound: another character
    cache.get(blend, "Head", ("m0", "m1"), sample)
    assert len(calls) == 3
    stat = blend.stat()
    os.utime(blend, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))  # the file changed
    cache.get(blend, "Head", ("m0", "m1"), sample)
    assert len(calls) == 4 and len(cache) == 2  # at most two kept
    assert cache.get(None, "Face", None, sample) is not None and len(calls) == 5  # the open file: never kept
