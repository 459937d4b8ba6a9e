"""Which FaceCap extension build serves which Blender: one build per Python generation of Blender.

Blender 4.2 to 5.0 run CPython 3.11 with NumPy 1.x; Blender 5.1 and later run CPython 3.13 with NumPy 2.
Compiled wheels (SciPy, OpenCV) load in one Python only, so each generation gets its own zips, with the
Blender versions it accepts written into each zip's manifest (``blender_version_min``/``_max``). The
newest build's range is open, so the next Blender release installs it without a new FaceCap release;
a Blender that changes its Python again needs a new build (``tests/e2e/test_blender_coverage.py`` fails
until it has one or is listed in ``EXCLUDED``). ``wheels.lock.toml`` holds each build's wheels.
"""

from dataclasses import dataclass

#: Blender's names for the platforms FaceCap builds zips for.
PLATFORMS = ("windows-x64", "linux-x64", "macos-arm64", "macos-x64")


def version_tuple(version):
    """``"5.1.0"`` or ``(5, 1, 0)`` -> ``(5, 1, 0)``."""
    if isinstance(version, tuple):
        return tuple(int(part) for part in version)
    return tuple(int(part) for part in str(version).split("."))


@dataclass(frozen=True)
class ExtensionBuild:
    """The zips for one Python generation of Blender.

    ``blender_max`` is exclusive, as Blender reads ``blender_version_max``; None leaves the range open.
    """

    name: str
    python: str
    blender_min: str
    blender_max: str | None
    platforms: tuple[str, ...]
    blenders: str  # the range as a user reads it

    def covers(self, blender_version):
        """Whether Blender ``blender_version`` (``"5.2.3"`` or a tuple) installs this build."""
        v = version_tuple(blender_version)
        return v >= version_tuple(self.blender_min) and (self.blender_max is None
                                                          or v < version_tuple(self.blender_max))

    def zip_name(self, version, platform):
        """``facecap-<version>-<build>-<platform>.zip`` (the platform as Blender writes it: ``linux_x64``)."""
        return f"facecap-{version}-{self.name}-{platform.replace('-', '_')}.zip"


BUILDS = (
    ExtensionBuild("blender4.2-5.0", "3.11", "4.2.0", "5.1.0", PLATFORMS, "Blender 4.2 LTS to 5.0"),
    # Blender 5.0 dropped Intel Macs, so there is no macos-x64 zip for 5.1 and later.
    ExtensionBuild("blender5.1-and-newer", "3.13", "5.1.0", None, ("windows-x64", "linux-x64", "macos-arm64"),
                   "Blender 5.1 and newer"),
)


@dataclass(frozen=True)
class Exclusion:
    """Blender releases no build serves, on purpose: those below ``below`` (if set) on ``platform``
    (if set, else on every platform)."""

    reason: str
    below: str | None = None
    platform: str | None = None

    def excludes(self, blender_version, platform):
        if self.platform is not None and platform != self.platform:
            return False
        return self.below is None or version_tuple(blender_version) < version_tuple(self.below)


EXCLUDED = (
    Exclusion("Blender before 4.2 has no extensions (no blender_manifest.toml, no bundled wheels)", below="4.2.0"),
    Exclusion("OpenCV 4 publishes no Windows-on-ARM wheel (SciPy does); the video features need OpenCV",
              platform="windows-arm64"),
)


def build_for_python(python):
    """The build for Blenders running Python ``python`` (``"3.13"`` or ``(3, 13)``), or None."""
    text = ".".join(map(str, python[:2])) if isinstance(python, tuple) else str(python)
    return next((b for b in BUILDS if b.python == text), None)


def build_named(name):
    """The build called ``name``; KeyError (listing the names) if none is."""
    for b in BUILDS:
        if b.name == name:
            return b
    raise KeyError(f"no extension build '{name}'; the builds are {', '.join(b.name for b in BUILDS)}")
