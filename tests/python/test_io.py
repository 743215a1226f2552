"""Readers and writers (issue 16 "Readers", issue 17 reader rows): every PCD/PLY variant written
byte by byte by an independent writer (tests/python/cloud_files.py), round trips through every
reader and writer, header/data mismatches, hostile files as one-line errors."""
import numpy as np
import pytest

import shotcrete
from cloud_files import pcd_bytes, ply_bytes, points, write, xyz_of
from conftest import cylinder_points

SURVEY = (500000.0, 4000000.0, 300.0)


def read_error(path) -> str:
    with pytest.raises(ValueError) as err:
        shotcrete.read_cloud(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg, msg  # one line naming the file
    return msg


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
@pytest.mark.parametrize("coord", ["f4", "f8"])
@pytest.mark.parametrize("order", ["xyz-first", "extras-first", "interleaved"])
def test_pcd_variants_read_exactly(tmp_path, data, coord, order):
    arr = points(257, coord, extras=True, normals=(order == "interleaved"), order=order)
    back = shotcrete.read_cloud(write(tmp_path / "c.pcd", pcd_bytes(arr, data)))
    np.testing.assert_array_equal(back.xyz, xyz_of(arr))  # float32 and float64 values exactly
    if order == "interleaved":
        nrm = np.column_stack([arr[c].astype(float) for c in ("normal_x", "normal_y", "normal_z")])
        np.testing.assert_array_equal(back.normals, nrm)
    else:
        assert not back.has_normals()


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("coord", ["f4", "f8"])
@pytest.mark.parametrize("order", ["xyz-first", "extras-first", "interleaved"])
def test_ply_variants_read_exactly(tmp_path, fmt, coord, order):
    arr = points(131, coord, extras=True, normals=(order == "extras-first"), order=order)
    back = shotcrete.read_cloud(write(tmp_path / "c.ply", ply_bytes(arr, fmt, faces=2 if order == "xyz-first" else 0)))
    np.testing.assert_array_equal(back.xyz, xyz_of(arr))
    assert back.has_normals() == (order == "extras-first")


@pytest.mark.parametrize("ext", [".pcd", ".ply"])
def test_double_survey_coordinates_keep_their_precision(tmp_path, ext):
    # Open3D's and CloudCompare's default: double x/y/z; read as (0, 0, 0) before.
    arr = points(300, "f8", extras=False, offset=SURVEY)
    data = pcd_bytes(arr, "binary") if ext == ".pcd" else ply_bytes(arr, "binary_little_endian")
    back = shotcrete.read_cloud(write(tmp_path / f"s{ext}", data))
    np.testing.assert_array_equal(back.xyz, xyz_of(arr))
    assert np.ptp(back.xyz[:, 1]) > 5.0  # not collapsed


# ---- round trips through our writers --------------------------------------------------------

def _parse_own_ply(path):
    """Our writer's binary PLY read by hand: the header's property types and the x/y/z values."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    props = [ln.split()[1:] for ln in raw[:end].decode().splitlines() if ln.startswith("property")]
    n = int(next(ln.split()[2] for ln in raw[:end].decode().splitlines() if ln.startswith("element vertex")))
    np_type = {"float": "<f4", "double": "<f8"}
    arr = np.frombuffer(raw[end:], dtype=[(name, np_type[t]) for t, name in props], count=n)
    return [t for t, name in props if name in "xyz"], xyz_of(arr)


@pytest.mark.parametrize("ext", [".pcd", ".ply", ".xyz", ".las"])
@pytest.mark.parametrize("where", ["local", "survey"])
def test_write_read_round_trip(tmp_path, ext, where):
    offset = np.asarray(SURVEY) if where == "survey" else np.zeros(3)
    xyz = cylinder_points(400) + offset
    nrm = -np.column_stack([np.zeros(400), xyz[:, 1] - offset[1], xyz[:, 2] - offset[2]]) / 5.6
    cloud = shotcrete.Cloud(xyz, nrm if ext != ".las" else None)
    back = shotcrete.read_cloud(shotcrete.write_cloud(tmp_path / f"c{ext}", cloud, np.arange(400.0)))
    # float32 within 1 ppm of the value near the origin; survey coordinates in double (PCD/PLY),
    # 12 significant digits (XYZ), or LAS's 0.1 mm scale.
    tol = {".pcd": 0.0, ".ply": 0.0, ".xyz": 5e-6, ".las": 5e-5}[ext] if where == "survey" else 5e-6
    tol = 5e-5 if ext == ".las" else tol
    np.testing.assert_allclose(back.xyz, xyz, rtol=0, atol=tol)
    if ext != ".las":
        np.testing.assert_allclose(back.normals, nrm, atol=1e-6)
    if ext == ".ply":
        types, own = _parse_own_ply(tmp_path / "c.ply")
        assert types == 3 * (["double"] if where == "survey" else ["float"])
        np.testing.assert_array_equal(own, back.xyz)


# ---- header / data mismatches -----------------------------------------------------------------

@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_pcd_points_lower_than_data_is_an_error(tmp_path, data):
    arr = points(200, "f4")
    msg = read_error(write(tmp_path / "half.pcd", pcd_bytes(arr, data, points_field=100, width=100)))
    assert "100" in msg and ("200" in msg or "bytes" in msg)


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_pcd_points_higher_than_data_is_an_error(tmp_path, data):
    arr = points(200, "f8")
    msg = read_error(write(tmp_path / "more.pcd", pcd_bytes(arr, data, points_field=300, width=300)))
    assert "300" in msg


@pytest.mark.parametrize("case, needle", [
    ({"points_field": -5, "width": -5}, "whole number"),
    ({"points_field": 200, "width": 100}, "WIDTH x HEIGHT"),
    ({"points_field": 99999999999999}, "beyond"),
])
def test_pcd_bad_counts(tmp_path, case, needle):
    assert needle in read_error(write(tmp_path / "bad.pcd", pcd_bytes(points(200, "f4"), "binary", **case)))


def test_pcd_malformed_values_and_fields(tmp_path):
    good = pcd_bytes(points(20, "f8", extras=False), "ascii")
    assert "not a number" in read_error(write(tmp_path / "a.pcd", good.replace(b"\n0.", b"\nnp.float64(0.", 1)))
    assert "values" in read_error(write(tmp_path / "b.pcd", good + b"1 2\n"))
    assert "SIZE" in read_error(write(tmp_path / "c.pcd", good.replace(b"SIZE 8 8 8", b"SIZE 8 8")))
    assert "TYPE" in read_error(write(tmp_path / "d.pcd", good.replace(b"SIZE 8 8 8", b"SIZE 8 3 8")))
    assert "not a PCD" in read_error(write(tmp_path / "e.pcd", b"\x00\x01garbage" * 100))


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
@pytest.mark.parametrize("count", [50, 150])
def test_ply_vertex_count_disagreeing_with_data_is_an_error(tmp_path, fmt, count):
    msg = read_error(write(tmp_path / "v.ply", ply_bytes(points(100, "f8"), fmt, vertex_count=count)))
    assert f"element vertex {count}" in msg or str(count) in msg


def test_ply_header_counts_checked_before_allocating(tmp_path):
    # 4e9 vertices in a 6 kB file: refused from the header, no allocation (was std::bad_alloc).
    msg = read_error(write(tmp_path / "huge.ply", ply_bytes(points(500, "f4", extras=False), "binary_little_endian",
                                                            vertex_count=4_000_000_000)))
    assert "4000000000" in msg and "truncated" in msg
    faces = ply_bytes(points(50, "f4", extras=False), "binary_little_endian", faces=1)
    faces = faces.replace(b"element face 1", b"element face 3000000000")
    assert "at least" in read_error(write(tmp_path / "faces.ply", faces))


def test_ply_malformed_headers(tmp_path):
    good = ply_bytes(points(20, "f4", extras=False), "ascii")
    assert "'z'" in read_error(write(tmp_path / "a.ply", good.replace(b"property float z", b"property float w")))
    assert "unknown type" in read_error(write(tmp_path / "b.ply", good.replace(b"float y", b"float16 y")))
    assert "'end_headr'" in read_error(write(tmp_path / "c.ply", good.replace(b"end_header", b"end_headr")))
    assert "format" in read_error(write(tmp_path / "d.ply", good.replace(b"ascii 1.0", b"utf8 1.0")))


@pytest.mark.parametrize("ext", [".xyz", ".csv", ".e57", ".las"])
def test_binary_garbage_is_one_clear_line(tmp_path, ext):
    # was: an empty 'error: ' (XYZ/CSV), 9 lines of libE57 dump (E57)
    garbage = np.random.default_rng(3).integers(0, 256, 4000, dtype=np.uint8).tobytes()
    msg = read_error(write(tmp_path / f"g{ext}", garbage))
    assert len(msg) > len(str(tmp_path / f"g{ext}")) + 10


def test_text_garbage_token_is_printable(tmp_path):
    msg = read_error(write(tmp_path / "t.xyz", b"1 2 3\n4 5 \xff\xfe\x80\n"))
    assert "'???' is not a number" in msg


# ---- units -----------------------------------------------------------------------------------

@pytest.mark.parametrize("scale, unit", [(1000.0, "mm"), (100.0, "cm")])
def test_units_hint_names_the_detected_scale(small_config, scale, unit):
    xyz = cylinder_points(500, radius=7.3) * scale  # a 12 m wide bay: 1,200 cm, 12,000 mm
    with pytest.raises(ValueError) as err:
        shotcrete.build_surface(shotcrete.Cloud(xyz), small_config)
    span = np.ptp(xyz, axis=0).max()
    msg = str(err.value)
    assert f"span {span:,.0f} units" in msg and f"--units {unit}" in msg, msg
    assert {"mm": "millimetres", "cm": "centimetres"}[unit] in msg


# ---- the CLI: each reader row of issues 16/17 ---------------------------------------------------

def test_cli_reader_rows_exit_2_with_one_line(tmp_path, run_cli):
    arr = points(400, "f4", extras=False)
    rows = {
        "half.pcd": pcd_bytes(arr, "ascii", points_field=200, width=200),
        "neg.pcd": pcd_bytes(arr, "ascii", points_field=-5, width=-5),
        "g.xyz": np.random.default_rng(1).integers(0, 256, 3000, dtype=np.uint8).tobytes(),
        "g.csv": np.random.default_rng(2).integers(0, 256, 3000, dtype=np.uint8).tobytes(),
        "g.e57": np.random.default_rng(3).integers(0, 256, 3000, dtype=np.uint8).tobytes(),
        "huge.ply": ply_bytes(arr, "binary_little_endian", vertex_count=4_000_000_000),
    }
    for name, data in rows.items():
        r = run_cli("plan", write(tmp_path / name, data), "--out", tmp_path / f"o_{name}")
        lines = [ln for ln in r.output.splitlines() if ln.strip() and "surface" not in ln]
        assert r.exit_code == 2, (name, r.output)
        assert len(lines) == 1 and lines[0].startswith("error: ") and name in lines[0], (name, r.output)


# ---- crashes and hangs the reader fuzzer found (tests/python/fuzz_readers.py) ------------------

def test_fuzz_finding_unknown_pcd_header_line(tmp_path):
    # PCL 1.13 stops its header parse at an unknown line and segfaulted reading binary_compressed data.
    good = pcd_bytes(points(40, "f4"), "binary_compressed")
    assert "'VERsION 0.7'" in read_error(write(tmp_path / "u.pcd", good.replace(b"VERSION 0.7", b"VERsION 0.7")))
    assert "unknown PCD header line 'FOO 1'" in read_error(write(tmp_path / "f.pcd", good.replace(b"WIDTH", b"FOO 1\nWIDTH")))
    assert "twice" in read_error(write(tmp_path / "t.pcd", good.replace(b"HEIGHT 1\n", b"HEIGHT 1\nHEIGHT 1\n")))


def test_fuzz_finding_bare_ply_property_line(tmp_path):
    # was a read past the end of the line's words (segfault)
    good = ply_bytes(points(10, "f4", extras=False), "binary_little_endian")
    assert "malformed PLY property" in read_error(write(tmp_path / "p.ply", good.split(b"property float y")[0] + b"property \n"))


def test_fuzz_finding_las_counts_checked_against_file_size(tmp_path):
    # a mutated VLR count / point data offset made laspy loop for minutes
    path = shotcrete.write_cloud(tmp_path / "c.las", shotcrete.Cloud(cylinder_points(50)))
    good = path.read_bytes()
    vlrs = good[:100] + (3_532_741_906).to_bytes(4, "little") + good[104:]
    assert "VLRs" in read_error(write(tmp_path / "v.las", vlrs))
    offset = good[:96] + (1_497_741_424).to_bytes(4, "little") + good[100:]
    assert "do not fit" in read_error(write(tmp_path / "o.las", offset))
    assert "truncated" in read_error(write(tmp_path / "t.las", good[:-100]))


@pytest.mark.parametrize("data", ["ascii", "binary"])
def test_pcd_extra_field_with_count_above_one(tmp_path, data):
    # a descriptor-like field of COUNT 3 between y and z: offsets must follow SIZE x COUNT
    n = 30
    arr = np.zeros(n, dtype=[("x", "<f8"), ("y", "<f8"), ("desc", "<f4", (3,)), ("z", "<f8")])
    xyz = cylinder_points(n) + np.asarray(SURVEY)
    arr["x"], arr["y"], arr["z"] = xyz.T
    arr["desc"] = np.arange(3 * n, dtype=np.float32).reshape(n, 3)
    head = (f"VERSION 0.7\nFIELDS x y desc z\nSIZE 8 8 4 8\nTYPE F F F F\nCOUNT 1 1 3 1\nWIDTH {n}\nHEIGHT 1\n"
            f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n").encode()
    if data == "ascii":
        rows = [[float(a["x"]), float(a["y"]), *map(float, a["desc"]), float(a["z"])] for a in arr]
        body = "".join(" ".join(repr(v) for v in row) + "\n" for row in rows).encode()
    else:
        body = arr.tobytes()
    back = shotcrete.read_cloud(write(tmp_path / "d.pcd", head + body))
    np.testing.assert_array_equal(back.xyz, xyz)
