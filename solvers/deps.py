"""Optional libraries (scipy, OpenCV), imported when a feature first needs them.

Blender ships numpy but neither scipy nor OpenCV; the extension zip for each platform bundles both
(``python -m facecap build-extension``, docs/install.md). When one cannot be imported (a zip without
the wheels, a source checkout linked into Blender, a damaged install) the feature raises
``MissingDependencyError`` saying what to install: inside Blender the zip built for this computer, since
an artist cannot pip-install into Blender's Python; outside Blender the pip package. Importing is
deferred so that enabling the add-on never loads scipy or OpenCV.
"""

import importlib
import platform
import sys
from pathlib import Path

from .errors import FacecapError

#: Top-level module -> the PyPI package that provides it (as bundled by wheels.lock.toml).
PACKAGES = {"scipy": "scipy", "cv2": "opencv-contrib-python-headless"}
_MANIFEST = Path(__file__).resolve().parents[1] / "blender_manifest.toml"


class MissingDependencyError(FacecapError):
    """A feature needs a library that cannot be imported here; the message says which build to install."""

    def __init__(self, module, feature, reason):
        self.module, self.feature = module, feature
        top = module.split(".")[0]
        package = PACKAGES.get(top, top)
        what = package if package == top else f"{package} ({top})"
        head = f"{feature} needs {what}, which cannot be imported here ({reason})"
        if "bpy" in sys.modules:
            advice = (f"install the FaceCap build for this computer, {extension_zip_name()}, with Edit > "
                      "Preferences > Get Extensions > Install from Disk: it bundles scipy and OpenCV")
        else:
            advice = f"install it into this Python: pip install {package}"
        super().__init__(f"{head}; {advice}")


def blender_platform():
    """This computer's platform in Blender's naming (``linux-x64``, ``windows-x64``, ``macos-arm64``, ...)."""
    system = {"darwin": "macos"}.get(platform.system().lower(), platform.system().lower())
    machine = platform.machine().lower()
    machine = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64"}.get(machine, machine)
    return f"{system}-{machine}"


def extension_zip_name():
    """The name of the extension zip built for this platform, e.g. ``facecap-0.1.0-linux_x64.zip``."""
    version = "<version>"
    try:
        import tomllib

        version = tomllib.loads(_MANIFEST.read_text(encoding="utf-8"))["version"]
    except (OSError, ValueError, KeyError):
        pass  # the name without a version is still the right advice
    return f"facecap-{version}-{blender_platform().replace('-', '_')}.zip"


def require(module, feature):
    """Import and return ``module``, or raise ``MissingDependencyError`` naming ``feature``.

    Parameters
    ----------
    module : str
        Dotted module name, e.g. ``"scipy.linalg.lapack"`` or ``"cv2"``.
    feature : str
        What needs it, as the user knows it (``"Clean Markers"``), starting with a capital.
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingDependencyError(module, feature, str(exc) or type(exc).__name__) from exc
