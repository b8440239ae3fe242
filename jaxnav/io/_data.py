"""Where the real datasets live: one lookup shared by every loader in :mod:`jaxnav.io`.

The datasets are never copied into the repository. A loader finds its folder
``<data>/<dataset>`` with ``<data>`` taken, in this order, from an explicit
``root``, the environment variable :data:`ENV_VAR`, ``../shared/data``
relative to the current directory, and ``../shared/data`` relative to the
repository root.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

ENV_VAR = "JAXNAV_DATA"
"""Environment variable naming the data folder (the parent of each dataset's folder)."""

_REPO_ROOT = Path(__file__).resolve().parents[2]
_DEFAULT_RELATIVE = Path("..") / "shared" / "data"


def data_candidates(root: str | os.PathLike | None) -> list[Path]:
    """The data folders to try, in order (see the module docstring)."""
    if root is not None:
        return [Path(root)]
    env = os.environ.get(ENV_VAR)
    if env:
        return [Path(env)]
    return [Path.cwd() / _DEFAULT_RELATIVE, _REPO_ROOT / _DEFAULT_RELATIVE]


def find_dataset(root: str | os.PathLike | None, dataset: str, is_dataset: Callable[[Path], bool], title: str) -> Path:
    """The folder of ``dataset``: ``<data>/<dataset>`` or ``<data>`` itself, the first where ``is_dataset`` holds.

    Raises:
        FileNotFoundError: naming the paths tried and the environment variable.
    """
    tried = []
    for base in data_candidates(root):
        for folder in (base / dataset, base):
            if is_dataset(folder):
                return folder.resolve()
        tried.append(str((base / dataset).resolve()))
    raise FileNotFoundError(
        f"{title} not found at {' or '.join(tried)}. Pass root=<folder holding {dataset}/> or set the "
        f"environment variable {ENV_VAR} to it."
    )
