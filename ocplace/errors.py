"""Typed errors. Each message says what went wrong and what the user can do about it."""


class OcplaceError(Exception):
    """Base class of every error ocplace raises on purpose."""


class MissingAssetPackage(OcplaceError):
    """An object source package is not installed."""


class UnknownObject(OcplaceError, KeyError):
    """An object name that is not in the library."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class AssetBuildError(OcplaceError):
    """An object could not be processed into the library."""


class LibraryNotBuilt(OcplaceError):
    """The object library cache is missing or incomplete."""


class SceneError(OcplaceError):
    """A scene could not be built, settled or rendered."""


class ParseError(OcplaceError, ValueError):
    """An instruction that cannot be turned into `<reference, relation>` tuples."""
