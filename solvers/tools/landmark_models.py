"""``python -m facecap landmark-models``: the face-landmark models into the facecap cache, outside Blender.

The three MediaPipe face-mesh files are taken out of the locked ``mediapipe`` 0.10.21 wheel (the
``[[asset]]`` entries of ``wheels.lock.toml``: downloaded once with pip, hash checked, the same fetch
the extension build uses), so ``[tracking] method = "landmarks"`` then runs with no download.
"""

import argparse
import os
from pathlib import Path

from ..errors import FacecapError
from ..video.face_models import MODEL_FILES, cache_models_dir
from .build_extension import fetch_assets, read_assets


def install_models(cache_dir=None, *, log=print):
    """Write the three model files into :func:`~..video.face_models.cache_models_dir`; returns it."""
    wanted = set(MODEL_FILES.values())
    assets = [a for a in read_assets() if Path(a.target).name in wanted]
    if {Path(a.target).name for a in assets} != wanted:
        raise FacecapError("wheels.lock.toml does not lock the face-landmark models (asset entries for "
                           + ", ".join(sorted(wanted)) + ")")
    target = cache_models_dir()
    target.mkdir(parents=True, exist_ok=True)
    for asset, data in fetch_assets(assets, cache_dir, log=log).items():
        path = target / Path(asset.target).name
        tmp = path.with_name(path.name + ".part")
        tmp.write_bytes(data)
        os.replace(tmp, path)  # atomic: a reader never sees half a model
    return target


def main(argv=None):
    parser = argparse.ArgumentParser(prog="facecap landmark-models",
                                     description="Put MediaPipe's face-mesh models into the facecap cache.")
    parser.parse_args(argv)
    target = install_models()
    print(f"face-landmark models in {target}: {', '.join(MODEL_FILES.values())}")
    return 0
