"""``python -m facecap rig-bench``: every test rig's figures in one run (``rig_bench``, ``rig_bench_mixed``,
``rig_bench_human``)."""

import tempfile
from pathlib import Path

from ...solvers.io.outputs import check_files_in
from ..render.docs_images import DEFAULT_OUT
from .rig_bench import control_rig_figures, rigify_figures
from .rig_bench_human import human_figures
from .rig_bench_mixed import mixed_rig_figures


def rig_bench(*, capture=None, frames=3600, sample_frames=600, docs=None, repeat=1, reference=False, long_only=False,
              say=print, overwrite=False):
    """The figures of every test rig (a dict, also printed through ``say``): the control rig and its
    correctives, the mixed bone/slider rig (``sample_frames`` against its plain keys, ``frames`` for
    its time), the Rigify face (a ``frames`` take; ``capture`` against the shape keys), the whole
    Rigify human (time per pose; ``capture`` onto it); ``long_only``: only the long Rigify take. ``docs``: the
    folder of the picture, through the output policy before anything runs (the checkout's docs/images is
    facecap's own; elsewhere ``overwrite`` lets it replace a file facecap did not write)."""
    if docs is not None:
        check_files_in(docs, ["rigify_face.png"], "--docs", "png", inputs={"--capture": capture}, overwrite=overwrite,
                       owned=(DEFAULT_OUT,))
    with tempfile.TemporaryDirectory(prefix="facecap-rig-bench-") as tmp:
        figures = {} if long_only else control_rig_figures(tmp, sample_frames, say)
        if not long_only:
            figures["mixed"] = mixed_rig_figures(tmp, sample_frames, say, long_frames=frames)
        rigify = Path(tmp) / "rigify"
        rigify.mkdir()
        figures["rigify"] = rigify_figures(rigify, None if long_only else capture, frames, say, docs, repeat=repeat,
                                           reference=reference, long_only=long_only)
        if not long_only:
            human = Path(tmp) / "human"
            human.mkdir()
            figures["human"] = human_figures(human, capture, say, repeat=max(repeat, 5))
    return figures
