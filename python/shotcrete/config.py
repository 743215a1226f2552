"""The one configuration: ``config/default.yaml`` loaded into the C++ ``Config`` struct.

Keys, ranges and units live once, in the core's field table; this module finds files and reads a
user's file strictly before the core parses it (``check_config_text``).
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import yaml

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
    check_config_text(path.read_bytes(), path)
    return Config.load(str(path))


_BOOL_TAG = "tag:yaml.org,2002:bool"


@lru_cache(maxsize=1)
def _bool_keys() -> frozenset:
    """"section.key" of every boolean field (from the core's defaults)."""
    sections = yaml.safe_load(Config().to_yaml())
    return frozenset(f"{s}.{k}" for s, keys in sections.items() for k, v in keys.items() if isinstance(v, bool))


def check_config_text(data: bytes, path: Path) -> None:
    """ValueError naming the line unless ``data`` is UTF-8 YAML without duplicate keys, with a real
    YAML boolean (true/false, not the text "yes") for every boolean key. The core checks the rest."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise ValueError(f"{path} line {line}: not UTF-8 text (byte 0x{data[exc.start]:02x})") from None
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: malformed YAML: {' '.join(str(exc).split())}") from None
    _check_node(root, path, "")


def _check_node(node, path: Path, prefix: str) -> None:
    if isinstance(node, yaml.SequenceNode):
        for item in node.value:
            _check_node(item, path, prefix)
    if not isinstance(node, yaml.MappingNode):
        return
    first_line: dict[str, int] = {}
    for key_node, value in node.value:
        name = f"{prefix}{key_node.value}" if isinstance(key_node, yaml.ScalarNode) else f"{prefix}?"
        line = key_node.start_mark.line + 1
        if name in first_line:
            raise ValueError(f"{path} line {line}: duplicate key '{name}' (first on line {first_line[name]})")
        first_line[name] = line
        if name in _bool_keys() and value.tag != _BOOL_TAG:
            shown = value.value if isinstance(value, yaml.ScalarNode) else type(value).__name__
            raise ValueError(f"{path} line {value.start_mark.line + 1}: config key '{name}' must be true or false "
                             f"(a YAML boolean), got {shown!r}")
        _check_node(value, path, name + ".")
