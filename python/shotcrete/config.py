"""The one configuration: ``config/default.yaml`` loaded into the C++ ``Config`` struct.

Keys, ranges and units live once, in the core's field table; this module finds files and reads a
user's file strictly before the core parses it (``check_config_text``).
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import yaml

from ._core import Config
from .io import check_text

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
    """ValueError naming the line unless ``data`` is UTF-8 YAML (no control characters, no CR
    without LF: io.check_text) without duplicate keys, with a real YAML boolean (true/false, not the
    text "yes") for every boolean key. The core checks the rest."""
    text = check_text(data, path)
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        _check_node(root, path, "")
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: malformed YAML: {' '.join(str(exc).split())}") from None
    except RecursionError:  # PyYAML composes, and _check_node walks, nested collections recursively
        raise ValueError(f"{path}: malformed YAML: collections nested too deeply for a config") from None


def _check_node(node, path: Path, prefix: str, seen: set | None = None) -> None:
    if not isinstance(node, (yaml.SequenceNode, yaml.MappingNode)):
        return
    # An alias is its anchored node once more: walk each node once (per name while the name can still
    # become a "section.key"), or nested aliases ("billion laughs") take exponential time.
    seen = set() if seen is None else seen
    visit = (id(node), prefix) if prefix.count(".") < 2 else id(node)
    if visit in seen:
        return
    seen.add(visit)
    if isinstance(node, yaml.SequenceNode):
        for item in node.value:
            _check_node(item, path, prefix, seen)
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
        _check_node(value, path, name + ".", seen)
