"""Independent PCD and PLY writers for the reader tests: plain bytes from numpy structured arrays,
written from the format specifications (PCD v0.7, PLY 1.0), sharing no code with the readers.
Also the mutation fuzzer's building blocks."""
from __future__ import annotations

from pathlib import Path

import numpy as np

PCD_TYPE = {"f": "F", "u": "U", "i": "I"}
PLY_TYPE = {"f4": "float", "f8": "double", "u1": "uchar", "i1": "char", "u2": "ushort", "i2": "short",
            "u4": "uint", "i4": "int"}


def points(n: int, coord: str = "f8", extras: bool = True, normals: bool = False, offset=(0.0, 0.0, 0.0),
           order: str = "xyz-first", seed: int = 0) -> np.ndarray:
    """A structured array of n points: x/y/z of dtype ``coord`` on a cylinder (radius 5.6 m),
    plus extra fields (intensity float, ring ushort, label uchar) placed before, between or after
    x/y/z (``order``), plus normal_x/y/z (float) when ``normals``."""
    rng = np.random.default_rng(seed)
    theta, d = rng.uniform(0.5, 2.5, n), rng.uniform(0.0, 1.2, n)
    xyz = np.column_stack([d, 5.6 * np.cos(theta), 5.6 * np.sin(theta)]) + np.asarray(offset)
    fields = [("x", coord), ("y", coord), ("z", coord)]
    if extras:
        extra = [("intensity", "f4"), ("ring", "u2"), ("label", "u1")]
        if order == "extras-first":
            fields = extra + fields
        elif order == "interleaved":
            fields = [("x", coord), extra[0], ("z", coord), extra[1], ("y", coord), extra[2]]
        else:
            fields = fields + extra
    if normals:
        fields += [("normal_x", "f4"), ("normal_y", "f4"), ("normal_z", "f4")]
    arr = np.zeros(n, dtype=[(name, "<" + t) for name, t in fields])
    for k, name in enumerate("xyz"):
        arr[name] = xyz[:, k]
    if extras:
        arr["intensity"] = rng.uniform(0, 100, n)
        arr["ring"] = rng.integers(0, 64, n)
        arr["label"] = rng.integers(0, 255, n)
    if normals:
        nrm = -np.column_stack([np.zeros(n), np.cos(theta), np.sin(theta)])
        for k, name in enumerate(("normal_x", "normal_y", "normal_z")):
            arr[name] = nrm[:, k]
    return arr


def xyz_of(arr: np.ndarray) -> np.ndarray:
    return np.column_stack([arr[c].astype(np.float64) for c in "xyz"])


def _ascii_rows(arr: np.ndarray) -> list[str]:
    cols = [arr[name] for name in arr.dtype.names]
    # repr of a Python float is exact for float64 and for float32 values (each is a float64).
    return [" ".join(repr(c[i].item()) for c in cols) for i in range(len(arr))]


def lzf_literals(data: bytes) -> bytes:
    """A valid LZF stream made of literal runs only (control byte L-1 < 32, then L bytes)."""
    out = bytearray()
    for i in range(0, len(data), 32):
        chunk = data[i:i + 32]
        out += bytes([len(chunk) - 1]) + chunk
    return bytes(out)


def pcd_bytes(arr: np.ndarray, data: str = "ascii", points_field: int | None = None,
              width: int | None = None) -> bytes:
    """PCD v0.7: header, then ascii rows, packed binary records, or binary_compressed (fields one
    after the other, LZF). ``points_field`` / ``width`` override the header's counts."""
    names = arr.dtype.names
    n = len(arr)
    header = "\n".join([
        "# .PCD v0.7 - Point Cloud Data file format", "VERSION 0.7",
        "FIELDS " + " ".join(names),
        "SIZE " + " ".join(str(arr.dtype[c].itemsize) for c in names),
        "TYPE " + " ".join(PCD_TYPE[arr.dtype[c].kind] for c in names),
        "COUNT " + " ".join("1" for _ in names),
        f"WIDTH {n if width is None else width}", "HEIGHT 1", "VIEWPOINT 0 0 0 1 0 0 0",
        f"POINTS {n if points_field is None else points_field}", f"DATA {data}"]) + "\n"
    if data == "ascii":
        body = ("\n".join(_ascii_rows(arr)) + "\n").encode()
    elif data == "binary":
        body = arr.tobytes()
    else:
        raw = b"".join(np.ascontiguousarray(arr[c]).tobytes() for c in names)
        packed = lzf_literals(raw)
        body = np.array([len(packed), len(raw)], dtype="<u4").tobytes() + packed
    return header.encode() + body


def ply_bytes(arr: np.ndarray, fmt: str = "ascii", vertex_count: int | None = None, faces: int = 0) -> bytes:
    """PLY 1.0: a vertex element with the array's fields as properties (nx/ny/nz for normals), then
    ``faces`` triangles (a list property); ascii, binary_little_endian or binary_big_endian."""
    rename = {"normal_x": "nx", "normal_y": "ny", "normal_z": "nz"}
    names = arr.dtype.names
    n = len(arr)
    lines = ["ply", f"format {fmt} 1.0", "comment written by the reader tests",
             f"element vertex {n if vertex_count is None else vertex_count}"]
    lines += [f"property {PLY_TYPE[arr.dtype[c].str[1:]]} {rename.get(c, c)}" for c in names]
    if faces:
        lines += [f"element face {faces}", "property list uchar int vertex_indices"]
    lines.append("end_header")
    head = ("\n".join(lines) + "\n").encode()
    tri = np.array([[i % n, (i + 1) % n, (i + 2) % n] for i in range(faces)], dtype=np.int64)
    if fmt == "ascii":
        rows = _ascii_rows(arr) + ["3 " + " ".join(str(v) for v in t) for t in tri]
        return head + ("\n".join(rows) + "\n").encode()
    endian = "<" if fmt == "binary_little_endian" else ">"
    body = arr.astype(arr.dtype.newbyteorder(endian)).tobytes()
    for t in tri:
        body += bytes([3]) + t.astype(endian + "i4").tobytes()
    return head + body


def write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path
