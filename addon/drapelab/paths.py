"""Where drapelab finds its files: the bundled assets and, optionally, the full Cusick dataset.

One locator for the whole project (the C++ tests follow the same rule in tests/native/test_support.hpp):

- ``assets_dir()``: the files drapelab needs to run (template meshes, a few real images, shipped presets).
  Inside an installed add-on they sit in the package (``drapelab/assets``); in a clone, in ``assets/`` at the
  repository root. Always present: a missing asset is an error, never a silent substitute.
- ``cusick_dataset_dir()``: the full public Cusick dataset (only tools and the tests that need it use it):
  ``$DRAPELAB_CUSICK_DIR`` when set (a folder without ``manifest.csv`` there counts as absent, which is how
  CI hides the dataset), else ``../shared/data/cusick`` beside the repository. ``None`` when absent.
"""
import os

__all__ = ["repository_root", "assets_dir", "template_dir", "cusick_dataset_dir", "require_cusick_dataset",
           "NO_DATASET_REASON", "DATASET_ENV"]

DATASET_ENV = "DRAPELAB_CUSICK_DIR"
NO_DATASET_REASON = ("needs the full Cusick dataset: not found at $DRAPELAB_CUSICK_DIR or "
                     "../shared/data/cusick beside the repository")

_PACKAGE = os.path.dirname(os.path.abspath(__file__))


def repository_root():
    """$DRAPELAB_ROOT, else the folder two levels above this package (the clone's root)."""
    return os.path.normpath(os.environ.get("DRAPELAB_ROOT") or os.path.join(_PACKAGE, "..", ".."))


def assets_dir():
    """The bundled assets: ``drapelab/assets`` inside an installed add-on, else ``<repository>/assets``."""
    packaged = os.path.join(_PACKAGE, "assets")
    if os.path.isdir(packaged):
        return packaged
    return os.path.join(repository_root(), "assets")


def template_dir():
    """The Cusick template meshes circle1..circle5.obj (bundled)."""
    return os.path.join(assets_dir(), "cusick", "template_meshes")


def cusick_dataset_dir():
    """The full Cusick dataset folder (holding manifest.csv), or None when it is absent."""
    env = os.environ.get(DATASET_ENV)
    folder = env if env is not None else os.path.join(repository_root(), "..", "shared", "data", "cusick")
    if folder and os.path.isfile(os.path.join(folder, "manifest.csv")):
        return os.path.normpath(folder)
    return None


def require_cusick_dataset():
    """cusick_dataset_dir(), or FileNotFoundError saying where it was looked for and how to point to it."""
    folder = cusick_dataset_dir()
    if folder is None:
        raise FileNotFoundError(f"drapelab: this {NO_DATASET_REASON}; set {DATASET_ENV} to the folder that "
                                "holds its manifest.csv")
    return folder
