"""The one configuration: ``config/default.yaml`` loaded into the C++ ``Config`` struct.

Keys, ranges and units live once, in the core's field table; this module only finds files.
"""
from __future__ import annotations

from pathlib import Path

from ._core import Config

_HERE = Path(__file__).resolve().parent


def _data_file(name: str) -> Path:
    """A data file shipped with the package (wheel) or lying in the source tree (editable)."""
    for candidate in (_HERE / "data" / name, _HERE.parents[1] / "data" / name,
                      _HERE.parents[1] / "config" / name):
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(f"shotcrete data file {name!r} is missing from the installation")


def default_config_path() -> Path:
    return _data_file("default.yaml")


def load_config(path: str | Path | None = None) -> Config:
    """Defaults from config/default.yaml, overridden by ``path`` if given.

    Raises ValueError naming an unknown key or an out-of-range value.
    """
    if path is None:
        return Config.load(str(default_config_path()))
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"config file {path} does not exist")
    return Config.load(str(path))
