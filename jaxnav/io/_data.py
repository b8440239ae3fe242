"""Where the real datasets live: one lookup shared by every loader in :mod:`jaxnav.io`.

The datasets are never copied into the repository. A loader finds its folder
``<data>/<dataset>`` with ``<data>`` taken, in this order, from an explicit
``root``, the environment variable :data:`ENV_VAR`, and the default data
folder :func:`default_data_dir`, an absolute path that never depends on the
current directory: ``../shared/data`` relative to the repository root when
jaxnav runs from a source checkout, else the user's data folder
``$XDG_DATA_HOME/jaxnav`` (``~/.local/share/jaxnav`` when the variable is unset).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

ENV_VAR = "JAXNAV_DATA"
"""Environment variable naming the data folder (the parent of each dataset's folder)."""

_REPO_ROOT = Path(__file__).resolve().parents[2]
_DEFAULT_RELATIVE = Path("..") / "shared" / "data"


class DataNotFoundError(FileNotFoundError):
    """A dataset folder that is in none of the places tried.

    Attributes:
        title: the dataset's name in words.
        dataset: the name of its folder.
        tried: the folders tried, resolved.
        source: where to get the data (a download page).
    """

    def __init__(self, title: str, dataset: str, tried: list[str], source: str) -> None:
        self.title, self.dataset, self.tried, self.source = title, dataset, tried, source
        super().__init__(self.explain(f"pass root=<folder holding {dataset}/>"))

    def explain(self, how_to_point: str) -> str:
        """The message, with ``how_to_point`` saying how to name the data folder (an argument, an option)."""
        return (
            f"{self.title} not found at {' or '.join(self.tried)}: {how_to_point} or set the environment "
            f"variable {ENV_VAR} to it; the data can be downloaded from {self.source}"
        )


def _source_checkout() -> Path | None:
    """The repository root when jaxnav runs from a source checkout, else None (an installed copy)."""
    if "site-packages" in _REPO_ROOT.parts or not (_REPO_ROOT / "pyproject.toml").is_file():
        return None
    return _REPO_ROOT


def default_data_dir() -> Path:
    """The default data folder, absolute and independent of the current directory: ``../shared/data``
    relative to the repository root when jaxnav runs from a source checkout, else the user's data
    folder ``$XDG_DATA_HOME/jaxnav`` (``~/.local/share/jaxnav`` when the variable is unset or relative)."""
    checkout = _source_checkout()
    if checkout is not None:
        return (checkout / _DEFAULT_RELATIVE).resolve()
    xdg = os.environ.get("XDG_DATA_HOME", "")
    base = Path(xdg) if os.path.isabs(xdg) else Path.home() / ".local" / "share"
    return base / "jaxnav"


def data_candidates(root: str | os.PathLike | None) -> list[Path]:
    """The data folders to try, in order (see the module docstring): ``[root]`` if given, else
    ``[$JAXNAV_DATA]`` if set, else ``[default_data_dir()]``."""
    if root is not None:
        return [Path(root)]
    env = os.environ.get(ENV_VAR)
    if env:
        return [Path(env)]
    return [default_data_dir()]


def find_dataset(
    root: str | os.PathLike | None, dataset: str, is_dataset: Callable[[Path], bool], title: str, source: str
) -> Path:
    """The folder of ``dataset``: ``<data>/<dataset>`` or ``<data>`` itself, the first where ``is_dataset`` holds.

    Raises:
        DataNotFoundError: naming the paths tried, the environment variable and ``source``,
            the page the data can be downloaded from.
    """
    tried = []
    for base in data_candidates(root):
        for folder in (base / dataset, base):
            if is_dataset(folder):
                return folder.resolve()
        tried.append(str((base / dataset).resolve()))
    raise DataNotFoundError(title, dataset, tried, source)
