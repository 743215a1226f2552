"""Cloud files: PCD/PLY/XYZ through the C++ core (PCL), LAS/LAZ through laspy, E57 through pye57."""
from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

from . import _core

UNIT_SCALES = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def _one_line(exc: Exception) -> str:
    """The first non-empty line of a library's message (libE57 appends a multi-line debug dump)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return lines[0] if lines else type(exc).__name__


# Characters a text input may not hold: controls but tab and the line ends LF and CRLF, a CR alone, and
# the Unicode line separators (NEL, U+2028/9).
_NOT_TEXT = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\x85\u2028\u2029]|\r(?!\n)")


def check_text(data: bytes, path: Path) -> str:
    """``data`` decoded as UTF-8, or ValueError naming the line of a non-UTF-8 byte, a control
    character or a lone carriage return. The core's text readers quote a bad cell or key in their
    message: undecodable bytes there made an empty ValueError, a CR or a control character a message
    that overwrites itself; and PyYAML reads a lone CR as a line break where yaml-cpp does not."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise ValueError(f"{path} line {line}: not UTF-8 text (byte 0x{data[exc.start]:02x})") from None
    bad = _NOT_TEXT.search(text)
    if bad:
        line = text.count("\n", 0, bad.start()) + 1
        what = ("a carriage return without a line feed" if bad.group() == "\r"
                else f"control character U+{ord(bad.group()):04X}")
        raise ValueError(f"{path} line {line}: {what} (only tabs and LF or CRLF line ends are allowed)")
    return text


def _check_las_header(path: Path) -> None:
    """The LAS public header's counts against the file size, before laspy reads (a mutated VLR
    count made laspy loop for minutes). Offsets from the LAS 1.0-1.4 specifications."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(375)
    if len(head) < 227 or head[:4] != b"LASF":
        raise ValueError(f"{path}: not a LAS/LAZ file (no LASF signature)")
    minor = head[25]
    header_size, offset, n_vlr = struct.unpack_from("<HII", head, 94)
    point_format, record_len, count = struct.unpack_from("<BHI", head, 104)
    if minor >= 4 and len(head) >= 255 and count == 0:
        count = struct.unpack_from("<Q", head, 247)[0]
    if not header_size <= offset <= size:
        raise ValueError(f"{path}: LAS header size {header_size} / point data offset {offset} do not fit the "
                         f"file of {size} bytes")
    if n_vlr * 54 > offset - header_size:
        raise ValueError(f"{path}: LAS header declares {n_vlr} VLRs, more than fit in {offset - header_size} bytes")
    compressed = point_format & 0xC0 or path.suffix.lower() == ".laz"
    if not compressed and count * record_len > size - offset:
        raise ValueError(f"{path}: LAS header declares {count} points of {record_len} bytes but the file holds "
                         f"{size - offset} bytes of point data (truncated, or the header overstates the count)")


def _cloud_from_array(xyz: np.ndarray, path: Path) -> _core.Cloud:
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"{path}: expected (N, 3) coordinates, got shape {xyz.shape}")
    return _core.Cloud(np.ascontiguousarray(xyz))


def read_cloud(path: str | Path) -> _core.Cloud:
    """Read a cloud in metres from .pcd, .ply, .xyz/.txt/.csv, .las/.laz or .e57.

    Raises ValueError for a missing, unknown or malformed file.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    ext = path.suffix.lower()
    if ext in (".las", ".laz"):
        import laspy

        _check_las_header(path)
        try:
            las = laspy.read(str(path))
        except Exception as exc:  # laspy raises several types for a bad file
            raise ValueError(f"{path}: not a readable LAS/LAZ file ({_one_line(exc)})") from None
        return _cloud_from_array(np.column_stack([las.x, las.y, las.z]), path)
    if ext == ".e57":
        import pye57

        try:
            e57 = pye57.E57(str(path))
            parts = []
            for i in range(e57.scan_count):
                scan = e57.read_scan(i, ignore_missing_fields=True, transform=True)
                parts.append(np.column_stack([scan["cartesianX"], scan["cartesianY"], scan["cartesianZ"]]))
        except Exception as exc:
            raise ValueError(f"{path}: not a readable E57 file ({_one_line(exc)})") from None
        if not parts:
            raise ValueError(f"{path}: the E57 file has no scans")
        return _cloud_from_array(np.vstack(parts), path)
    return _core.read_cloud(str(path))


def write_cloud(path: str | Path, cloud: _core.Cloud, scalar: np.ndarray | None = None) -> Path:
    """Write .pcd/.ply/.xyz (core) or .las (laspy); ``scalar`` goes to intensity (PCD/PLY) or a column."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() in (".las", ".laz"):
        import laspy

        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales = np.array([1e-4, 1e-4, 1e-4])
        header.offsets = cloud.xyz.min(axis=0) if len(cloud) else np.zeros(3)
        las = laspy.LasData(header)
        las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]
        las.write(str(path))
        return path
    if scalar is None:
        _core.write_cloud(str(path), cloud)
    else:
        _core.write_cloud(str(path), cloud, np.asarray(scalar, dtype=np.float64))
    return path
