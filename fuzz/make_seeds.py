#!/usr/bin/env python3
"""Writes the seed corpora for the fuzz targets into fuzz/corpus/<target>/.

Only the Python standard library is used. Run from anywhere:

    python3 fuzz/make_seeds.py

Seeds: the real test files (tests/data; the bunny cut to its first 200 lines,
plus a variant with the faces that only use those vertices), small
hand-written text inputs, tiny GeoTIFFs covering the sample types,
byte orders, BigTIFF, strips/tiles, deflate and the three georeferencing tags,
tiny 16-bit / 8-bit grayscale PNGs, small glTF / GLB files (external, subfolder
and data-URI buffers, sparse accessors, instancing, strips) and scene
descriptions naming the files of the fuzz targets' scratch folder, and four
small saved scenes (.rpk: empty, one triangle, two masked objects, a grid with
a terrain block) written from the format's description.
"""

import base64
import json
import shutil
import struct
import zlib
from pathlib import Path

FUZZ = Path(__file__).resolve().parent
ROOT = FUZZ.parent
DATA = ROOT / "tests" / "data"
CORPUS = FUZZ / "corpus"


def put(target: str, name: str, data) -> None:
    d = CORPUS / target
    d.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    (d / name).write_bytes(data)


# --- obj ---------------------------------------------------------------------

def obj_seeds() -> None:
    lines = (DATA / "bunny.obj").read_text().splitlines(keepends=True)
    head = lines[:200]
    put("obj", "bunny_head200.obj", "".join(head))
    n = sum(1 for l in head if l.startswith("v "))
    faces = [
        l for l in lines
        if l.startswith("f ") and all(int(t) <= n for t in l.split()[1:])
    ]
    put("obj", "bunny_head200_faces.obj", "".join(head + faces))
    put("obj", "polygons.obj",
        "v 1 1 0.5\nv 2 4 0.5\nv 3 9 0.5\nv 4 16 0.5\nv 5 25 0.5\n"
        "f 1 2 3 4\nf 5 3 1 2 4\nf 2 4 5\n")
    put("obj", "negative.obj",
        "v 1 1 0.5\nv 2 4 0.5\nv 3 9 0.5\nf -3 -2 -1\nv 4 16 0.5\n"
        "v 5 25 0.5\nv 6 36 0.5\nv 7 49 0.5\nf -4 -3 -2 -1\nf 1 -1 2\n")
    put("obj", "attributes.obj",
        "# header\nmtllib a.mtl\no a\nv 2 2 2 2\nv 2 0 0 1 0 0\nv 0 1 0\n"
        "vt 0 0\nvn 0 0 1\nusemtl m\ng b\ns 1\nf 1/1/1 2//1 3/1\n"
        "l 1 2 3\np 1\nf 1 2\n")
    put("obj", "crlf_bom.obj",
        "\ufeffv 1 1 0.5\r\nv 2 4 0.5\r\nv 3 9 0.5\r\nf 1 2 3\r\n")


# --- ray_file ----------------------------------------------------------------

def ray_seeds() -> None:
    put("ray_file", "basic.txt",
        "0 0 -5 0 0 1\n1 2 3\t4 5 6 7.5\n# comment\n\n"
        "  -1e3 2.5E-2 +3 0 -1 0 inf # trailing\nnan 0 0 1 1 1\n")
    put("ray_file", "crlf_bom.txt",
        "\ufeff0 0 1 0 0 -1\r\n0.5 0.5 10 0 0 -1 100\r\n")
    put("ray_file", "points.txt",
        "# x y z\n512745 4042455 400\n512800.5 4042000 -1e-3 # comment\n\n0 0 0\n")


# --- asc -----------------------------------------------------------------------

def asc_seeds() -> None:
    shutil.copy(DATA / "jacksboro_fault_dem_utm.asc",
                CORPUS / "asc" / "jacksboro_fault_dem_utm.asc")
    put("asc", "small_corner.asc",
        "ncols 3\nnrows 2\nxllcorner 100\nyllcorner 200\ncellsize 10\n1 2 3\n4 5 6\n")
    put("asc", "small_center.asc",
        "ncols 3\nnrows 2\nxllcenter 100\nyllcenter 200\ncellsize 10\n1 2 3 4 5 6\n")
    put("asc", "dxdy_nodata.asc",
        "\ufeffNCOLS 2\r\nNRows 3\r\nXLLCorner 0\r\nyllCORNER 0\r\nDX 2\r\ndy 4\r\n"
        "NODATA_value -9999\r\n1\r\n2 -9999\r\n3.5 4e1\r\n\r\n-9999.0\r\n")
    rows = (DATA / "jacksboro_fault_dem_utm.asc").read_text().splitlines()[5:9]
    put("asc", "jacksboro_5x4.asc",
        "ncols 5\nnrows 4\nxllcorner 512730\nyllcorner 4032150\ncellsize 30\n"
        "nodata_value nan\n" + "".join(" ".join(r.split()[:5]) + "\n" for r in rows))


# --- geotiff -------------------------------------------------------------------

# TIFF field types: (code, struct format)
SHORT, LONG, ASCII, DOUBLE, LONG8 = (3, "H"), (4, "I"), (2, "s"), (12, "d"), (16, "Q")


def tiff(entries, data_blocks, big=False, be=False):
    """Builds a TIFF with one IFD.

    entries: list of (tag, type, values); values may be the string
    "@k"/"#k" to mean "offsets of"/"byte counts of" data_blocks[k] (list).
    """
    e = ">" if be else "<"
    head = (b"MM" if be else b"II") + (
        struct.pack(e + "HHHQ", 43, 8, 0, 16) if big else struct.pack(e + "HI", 42, 8))
    ifd_at = len(head)
    n = len(entries)
    entry_size, count_fmt, inline = (20, "Q", 8) if big else (12, "I", 4)
    ifd_size = (8 if big else 2) + n * entry_size + (8 if big else 4)
    extra = bytearray()
    extra_at = ifd_at + ifd_size
    # image data goes after the IFD's out-of-line values; reserve by two passes
    blocks_len = sum(len(b) for blks in data_blocks for b in blks)

    def encode(typ, values):
        code, fmt = typ
        if fmt == "s":
            raw = values.encode() + b"\0"
            return code, len(raw), raw
        return code, len(values), struct.pack(e + fmt * len(values), *values)

    # first pass: sizes of out-of-line values
    def build(data_at):
        offsets = []
        pos = data_at
        for blks in data_blocks:
            o = []
            for b in blks:
                o.append(pos)
                pos += len(b)
            offsets.append(o)
        out_entries = []
        extra = bytearray()
        for tag, typ, values in sorted(entries, key=lambda t: t[0]):
            if isinstance(values, str) and values[0] in "@#":
                k = int(values[1:])
                values = offsets[k] if values[0] == "@" else [len(b) for b in data_blocks[k]]
            code, count, raw = encode(typ, values)
            if len(raw) <= inline:
                field = raw.ljust(inline, b"\0")
            else:
                field = struct.pack(e + count_fmt, extra_at + len(extra))
                extra += raw
                if len(extra) % 2:
                    extra += b"\0"
            out_entries.append(struct.pack(e + "HH" + count_fmt, tag, code, count) + field)
        ifd = struct.pack(e + ("Q" if big else "H"), n) + b"".join(out_entries) + \
            struct.pack(e + ("Q" if big else "I"), 0)
        return ifd, extra

    ifd, extra = build(0)
    data_at = extra_at + len(extra)
    ifd, extra = build(data_at)
    assert len(ifd) == ifd_size and data_at == extra_at + len(extra)
    out = head + ifd + extra + b"".join(b for blks in data_blocks for b in blks)
    assert len(out) == data_at + blocks_len
    return bytes(out)


def geokeys(raster_type):
    keys = [1, 1, 0, 0]
    body = [1024, 0, 1, 1]  # GTModelTypeGeoKey = projected
    if raster_type is not None:
        body += [1025, 0, 1, raster_type]
    body += [3072, 0, 1, 32617]  # ProjectedCSTypeGeoKey = UTM 17N
    keys[3] = len(body) // 4
    return keys + body


def geotiff_seeds() -> None:
    for f in DATA.glob("*.tif"):
        shutil.copy(f, CORPUS / "geotiff" / f.name)
    w, h = 4, 3
    vals = [483, 487, 491, 493, 475, -9999, 489, 490, 479, 485, 488, 487]
    georef_tp = [
        (33550, DOUBLE, [30.0, 30.0, 0.0]),
        (33922, DOUBLE, [0.0, 0.0, 0.0, 512730.0, 4042470.0, 0.0]),
    ]

    def base(bits, fmt, strip, extra_tags, compression=1):
        return [
            (256, SHORT, [w]), (257, SHORT, [h]), (258, SHORT, [bits]),
            (259, SHORT, [compression]), (262, SHORT, [1]), (273, LONG, "@0"),
            (277, SHORT, [1]), (278, SHORT, [h]), (279, LONG, "#0"),
            (284, SHORT, [1]), (339, SHORT, [fmt]),
        ] + extra_tags

    # Int16, PixelIsArea, GDAL nodata, little-endian
    for be in (False, True):
        e = ">" if be else "<"
        strip = struct.pack(e + "h" * len(vals), *vals)
        tags = base(16, 2, strip, georef_tp + [(34735, SHORT, geokeys(1)),
                                               (42113, ASCII, "-9999")])
        put("geotiff", f"int16_area_nodata_{'be' if be else 'le'}.tif",
            tiff(tags, [[strip]], be=be))
    # Float32, PixelIsPoint, ModelTransformationTag, deflate
    strip = zlib.compress(struct.pack("<" + "f" * len(vals), *[v + 0.25 for v in vals]))
    m = [30.0, 0, 0, 512745.0, 0, -30.0, 0, 4042455.0, 0, 0, 0, 0, 0, 0, 0, 1]
    tags = base(32, 3, strip, [(34264, DOUBLE, m), (34735, SHORT, geokeys(2))], compression=8)
    put("geotiff", "f32_point_matrix_deflate.tif", tiff(tags, [[strip]]))
    # Float64, no GeoKeyDirectory, BigTIFF
    strip = struct.pack("<" + "d" * len(vals), *[float(v) for v in vals])
    tags = base(64, 3, strip, georef_tp, compression=1)
    tags = [(t, LONG8 if t in (273, 279) else typ, v) for t, typ, v in tags]
    put("geotiff", "f64_bigtiff.tif", tiff(tags, [[strip]], big=True))
    # UInt8 / Int32 / UInt32
    for bits, fmt, code in ((8, 1, "B"), (32, 2, "i"), (32, 1, "I")):
        strip = struct.pack("<" + code * len(vals), *[abs(v) % (1 << bits) for v in vals])
        tags = base(bits, fmt, strip, georef_tp + [(34735, SHORT, geokeys(1))])
        put("geotiff", f"{'u' if fmt == 1 else 'i'}{bits}.tif", tiff(tags, [[strip]]))
    # UInt16, tiled 16x16 (image 20x18 -> 2x2 tiles), deflate
    tw, th, W, H = 16, 16, 20, 18
    tiles = []
    for ty in range(2):
        for tx in range(2):
            px = [((ty * th + y) * W + tx * tw + x) % 65536 for y in range(th) for x in range(tw)]
            tiles.append(zlib.compress(struct.pack("<" + "H" * len(px), *px)))
    tags = [
        (256, SHORT, [W]), (257, SHORT, [H]), (258, SHORT, [16]), (259, SHORT, [8]),
        (262, SHORT, [1]), (277, SHORT, [1]), (284, SHORT, [1]), (339, SHORT, [1]),
        (322, SHORT, [tw]), (323, SHORT, [th]), (324, LONG, "@0"), (325, LONG, "#0"),
    ] + georef_tp + [(34735, SHORT, geokeys(1))]
    put("geotiff", "u16_tiled_deflate.tif", tiff(tags, [tiles]))


# --- png16 ---------------------------------------------------------------------

def png(width, height, bit_depth, rows, color_type=0, interlace=0, filters=(0,)):
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + \
            struct.pack(">I", zlib.crc32(kind + body) & 0xffffffff)
    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, color_type, 0, 0, interlace)
    raw = b"".join(bytes([filters[i % len(filters)]]) + r for i, r in enumerate(rows))
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + \
        chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def png_seeds() -> None:
    w, h = 5, 4
    rows16 = [struct.pack(">" + "H" * w, *[(y * 9000 + x * 1111) % 65536 for x in range(w)])
              for y in range(h)]
    put("png16", "gray16_5x4.png", png(w, h, 16, rows16))
    rows8 = [bytes((y * 50 + x * 7) % 256 for x in range(w)) for y in range(h)]
    put("png16", "gray8_5x4.png", png(w, h, 8, rows8))
    # A 16-bit 1x1 and a filtered (Sub filter) 16-bit image.
    put("png16", "gray16_1x1.png", png(1, 1, 16, [b"\xff\xfe"]))
    # Rows with filter types 1..4 (Sub, Up, Average, Paeth) instead of 0.
    put("png16", "gray16_filters.png", png(w, h, 16, rows16, filters=[1, 2, 3, 4]))
    # An RGB image (rejected: unsupported format) to give the fuzzer that path.
    put("png16", "rgb8_2x2.png", png(2, 2, 8, [b"\x10\x20\x30" * 2] * 2, color_type=2))


# --- gltf --------------------------------------------------------------------

TRI = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0) + struct.pack("<4H", 0, 1, 2, 0)


def gltf_doc(uri, extra=None):
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "children": [1]}, {"mesh": 0, "scale": [2, 2, 2]}],
        "meshes": [{"name": "tri", "primitives": [
            {"attributes": {"POSITION": 0}, "indices": 1},
            {"attributes": {"POSITION": 0}, "mode": 5},
        ]}],
        "buffers": [{"byteLength": 44, "uri": uri} if uri else {"byteLength": 44}],
        "bufferViews": [{"buffer": 0, "byteLength": 36},
                        {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
        ],
    }
    doc.update(extra or {})
    return json.dumps(doc)


def gltf_seeds() -> None:
    # The fuzz target's scratch folder holds tri.bin and sub/tri.bin (fuzz/src/lib.rs).
    put("gltf", "external.gltf", gltf_doc("tri.bin"))
    put("gltf", "subfolder.gltf", gltf_doc("sub/tri.bin"))
    put("gltf", "data_uri.gltf", gltf_doc(
        "data:application/octet-stream;base64," + base64.b64encode(TRI).decode()))
    put("gltf", "sparse.gltf", json.dumps({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": 16, "uri": "data:,%00%00%00%00%00%00%80%3F%00%00%00%40%00%00%40%40"}],
        "bufferViews": [{"buffer": 0, "byteLength": 4}, {"buffer": 0, "byteOffset": 4, "byteLength": 12}],
        "accessors": [{"componentType": 5126, "count": 3, "type": "VEC3", "sparse": {
            "count": 1, "indices": {"bufferView": 0, "componentType": 5125},
            "values": {"bufferView": 1}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0, "matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 5, 6, 7, 1]}],
    }))
    body = gltf_doc(None).encode()
    body += b" " * (-len(body) % 4)
    chunks = struct.pack("<I", len(body)) + b"JSON" + body
    chunks += struct.pack("<I", len(TRI)) + b"BIN\0" + TRI
    put("gltf", "binary.glb", b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks)


# --- scene_description -------------------------------------------------------

def scene_description_seeds() -> None:
    # The fuzz target's scratch folder holds tri.obj, grid.asc, tri.gltf (fuzz/src/lib.rs).
    put("scene_description", "all.json", json.dumps({"objects": [
        {"file": "tri.obj", "mask": 1}, {"file": "grid.asc", "mask": 2},
        {"file": "./tri.gltf"}]}))
    put("scene_description", "one.json", '{"objects": [{"file": "grid.asc"}]}')
    put("scene_description", "empty.json", '{"objects": []}')
    put("scene_description", "dotdot.json", '{"objects": [{"file": "../tri.obj"}]}')


# --- rpk ---------------------------------------------------------------------
# Saved scenes written from the format description in src/rpk/mod.rs alone (an
# independent writer of the format: the fuzz target reads them back, and
# `RAYPICK_FUZZ_DEBUG=1 cargo fuzz run rpk corpus/rpk/<seed>` shows they load).

RPK_MAGIC = b"\x89RPK\r\n\x1a\n"
# Children per wide node (the WIDE section's nodes).
WIDTH = 8


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def rpk_tree(local, shape):
    """Depth-first nodes for `shape` over leaf-order triangles `local` (f32
    vertex triples): ("leaf", count) or ("inner", axis, left, right). Returns
    nodes [(min, parent, kind, max, first)] and the wide tree's one node."""
    nodes = []
    taken = [0]

    def build(s, parent):
        index = len(nodes)
        nodes.append(None)
        if s[0] == "leaf":
            first = taken[0]
            taken[0] += s[1]
            vs = [v for t in local[first:first + s[1]] for v in t]
            lo = [min(v[a] for v in vs) for a in range(3)]
            hi = [max(v[a] for v in vs) for a in range(3)]
            nodes[index] = (lo, parent, s[1], hi, first)
        else:
            left = build(s[2], index)
            right = build(s[3], index)
            lo = [min(nodes[left][0][a], nodes[right][0][a]) for a in range(3)]
            hi = [max(nodes[left][3][a], nodes[right][3][a]) for a in range(3)]
            nodes[index] = (lo, parent, 16 + s[1], hi, right)
        return index

    build(shape, 0)
    # The collapse of a tree of at most eight leaves: one wide node whose slots
    # are the leaves in order (inner children opened in place).
    slots = [0] if nodes[0][2] < 16 else [1, nodes[0][4]]
    while any(nodes[n][2] >= 16 for n in slots):
        i = next(k for k, n in enumerate(slots) if nodes[n][2] >= 16)
        slots[i:i + 1] = [slots[i] + 1, nodes[slots[i]][4]]
    assert len(slots) <= WIDTH
    wide = ([[0.0] * WIDTH for _ in range(3)], [[0.0] * WIDTH for _ in range(3)],
            [0] * WIDTH, [0] * WIDTH)
    for lane, n in enumerate(slots):
        lo, _, kind, hi, first = nodes[n]
        for a in range(3):
            wide[0][a][lane] = lo[a]
            wide[1][a][lane] = hi[a]
        wide[2][lane] = first
        wide[3][lane] = kind
    return nodes, [wide] if nodes else []


def rpk_file(positions, triangles, objects, leaf_ids=(), shape=None, blocks=()):
    """A version 3 .rpk. objects: (name, first triangle, count, first vertex,
    mask, (columns, rows) or None); leaf_ids: scene triangles in leaf order;
    blocks: (rows, cols, node, triangles, min, max) with (start, end) ranges."""
    if positions:
        lo = [min(p[a] for p in positions) for a in range(3)]
        hi = [max(p[a] for p in positions) for a in range(3)]
        origin = [lo[a] + (hi[a] - lo[a]) * 0.5 for a in range(3)]
    else:
        origin = [0.0, 0.0, 0.0]
    local = [[[f32(positions[i][a] - origin[a]) for a in range(3)] for i in triangles[t]]
             for t in leaf_ids]
    nodes, wide = rpk_tree(local, shape) if shape else ([], [])
    mask_of = {}
    for _, first, count, _, mask, _ in objects:
        for t in range(first, first + count):
            mask_of[t] = mask
    masks = ([mask_of[t] for t in leaf_ids]
             if any(o[4] != 0xFFFFFFFF for o in objects) else [])
    names = b"".join(o[0].encode() for o in objects)
    summary = struct.pack("<10Q", len(positions), len(triangles), len(objects), len(names),
                          len(nodes), len(leaf_ids), len(blocks), len(wide),
                          1 if wide else 0, len(masks))
    summary += struct.pack("<6d", *origin, *origin)
    payloads = [
        (b"SUMM", summary),
        (b"VERT", b"".join(struct.pack("<3d", *p) for p in positions)),
        (b"TRIS", b"".join(struct.pack("<3I", *t) for t in triangles)),
        (b"OBJS", b"".join(
            struct.pack("<10I", k, first, count, vertex, mask, int(grid is not None),
                        *(grid or (0, 0)), len(name.encode()), 0)
            for k, (name, first, count, vertex, mask, grid) in enumerate(objects))),
        (b"NAME", names),
        (b"NODE", b"".join(struct.pack("<3fI3fI", *lo, parent << 5 | kind, *hi, first)
                           for lo, parent, kind, hi, first in nodes)),
        (b"LTRI", b"".join(struct.pack("<9f", *(c for v in t for c in v)) for t in local)),
        (b"TIDS", b"".join(struct.pack("<I", t) for t in leaf_ids)),
        (b"MASK", b"".join(struct.pack("<I", m) for m in masks)),
        (b"BLKS", b"".join(
            struct.pack("<8I9d", *rows, *cols, node, *tris, 0, *bmin, *bmax,
                        *[bmin[a] + (bmax[a] - bmin[a]) * 0.5 for a in range(3)])
            for rows, cols, node, tris, bmin, bmax in blocks)),
        (b"WIDE", b"".join(
            struct.pack("<24f24f8I8BB23x", *(v for axis in lo for v in axis),
                        *(v for axis in hi for v in axis), *child, *kind,
                        sum(1 << lane for lane in range(WIDTH) if kind[lane]))
            for lo, hi, child, kind in wide)),
    ]
    # Each payload starts on a 64-byte boundary, its 16-byte section header right
    # before it and zero bytes before that; zero bytes pad it to the next boundary.
    body = b""
    for tag, p in payloads:
        at = 32 + len(body)
        start = -(-(at + 16) // 64) * 64
        body += b"\0" * (start - 16 - at) + tag + struct.pack("<IQ", zlib.crc32(p), len(p))
        body += p + b"\0" * (-len(p) % 64)
    head = RPK_MAGIC + struct.pack("<IIQI", 3, len(payloads), 32 + len(body), 0)
    return head + struct.pack("<I", zlib.crc32(head)) + body


def rpk_seeds() -> None:
    put("rpk", "empty.rpk", rpk_file([], [], []))
    tri = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)]
    put("rpk", "one_triangle.rpk",
        rpk_file(tri, [(0, 1, 2)], [("tri", 0, 1, 0, 0xFFFFFFFF, None)], [0], ("leaf", 1)))
    # Two objects with masks; object "b"'s last triangle has zero area and is
    # left out of the tree.
    positions = tri + [(2.0, 0.0, 1.0), (3.0, 0.0, 1.0), (2.0, 1.0, 1.5), (3.0, 1.0, 2.0)]
    put("rpk", "masks.rpk", rpk_file(
        positions, [(0, 1, 2), (3, 4, 5), (4, 6, 5), (3, 3, 4)],
        [("a", 0, 1, 0, 1, None), ("b", 1, 3, 3, 6, None)], [0, 1, 2],
        ("inner", 0, ("leaf", 1), ("inner", 1, ("leaf", 1), ("leaf", 1)))))
    # A 3 x 3 height grid (8 triangles, grid numbering) split at x = 1, with one
    # terrain block.
    heights = [1.0, 2.0, 1.5, 0.5, 3.0, 2.0, 1.0, 1.0, 2.5]
    grid = [(float(c), float(2 - r), heights[3 * r + c]) for r in range(3) for c in range(3)]
    triangles = []
    for r in range(2):
        for c in range(2):
            nw, ne, sw, se = 3 * r + c, 3 * r + c + 1, 3 * (r + 1) + c, 3 * (r + 1) + c + 1
            triangles += [(nw, sw, se), (nw, se, ne)]
    bmin = [min(p[a] for p in grid) for a in range(3)]
    bmax = [max(p[a] for p in grid) for a in range(3)]
    put("rpk", "grid.rpk", rpk_file(
        grid, triangles, [("grid.asc", 0, 8, 0, 0xFFFFFFFF, (3, 3))],
        [0, 1, 4, 5, 2, 3, 6, 7], ("inner", 0, ("leaf", 4), ("leaf", 4)),
        [((0, 2), (0, 2), 0, (0, 8), bmin, bmax)]))


# --- ply, stl -----------------------------------------------------------------

def ply_seeds() -> None:
    import gzip
    import struct
    for f in sorted((DATA / "formats").glob("*.ply")):
        put("ply", f.name, f.read_bytes())
    verts = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.0, 1.0, 0.5), (0.0, 1.0, 0.25)]
    faces = [(0, 1, 2, 3), (0, 2, 3)]

    def header(fmt, coord, count, index, extra=""):
        return (f"ply\nformat {fmt} 1.0\ncomment seed\nelement vertex {len(verts)}\n"
                f"property {coord} x\nproperty {coord} y\nproperty {coord} z\n{extra}"
                f"element face {len(faces)}\nproperty list {count} {index} vertex_indices\n"
                "end_header\n").encode()

    ascii_body = "".join(f"{x} {y} {z}\n" for x, y, z in verts)
    ascii_body += "".join(f"{len(f)} " + " ".join(map(str, f)) + "\n" for f in faces)
    put("ply", "quad_ascii.ply", header("ascii", "float", "uchar", "int") + ascii_body.encode())
    for fmt, end in (("binary_little_endian", "<"), ("binary_big_endian", ">")):
        for coord, code in (("float", "f"), ("double", "d")):
            body = b"".join(struct.pack(end + 3 * code, *v) for v in verts)
            body += b"".join(struct.pack(end + "B" + len(f) * "I", len(f), *f) for f in faces)
            data = header(fmt, coord, "uchar", "uint") + body
            put("ply", f"quad_{fmt}_{coord}.ply", data)
    put("ply", "quad_ascii.ply.gz", gzip.compress(
        header("ascii", "float", "uchar", "int") + ascii_body.encode(), mtime=0))


def stl_seeds() -> None:
    import struct
    for f in sorted((DATA / "formats").glob("*.stl")):
        put("stl", f.name, f.read_bytes())
    tris = [((0, 0, 0), (1, 0, 0), (0, 1, 0)), ((1, 0, 0), (1, 1, 0.5), (0, 1, 0))]
    text = "solid seed\n"
    for t in tris:
        text += " facet normal 0 0 1\n  outer loop\n"
        text += "".join(f"   vertex {x} {y} {z}\n" for x, y, z in t)
        text += "  endloop\n endfacet\n"
    put("stl", "two_ascii.stl", text + "endsolid seed\n")
    body = b"".join(struct.pack("<12fH", 0, 0, 1, *[c for v in t for c in v], 0) for t in tris)
    put("stl", "two_binary.stl", b"binary seed".ljust(80, b" ") + struct.pack("<I", len(tris)) + body)
    put("stl", "two_binary_solid.stl",
        b"solid but binary".ljust(80, b" ") + struct.pack("<I", len(tris)) + body)


if __name__ == "__main__":
    for t in ("obj", "ray_file", "asc", "geotiff", "png16", "gltf", "scene_description", "rpk",
              "ply", "stl"):
        (CORPUS / t).mkdir(parents=True, exist_ok=True)
    obj_seeds()
    ray_seeds()
    asc_seeds()
    geotiff_seeds()
    png_seeds()
    gltf_seeds()
    scene_description_seeds()
    rpk_seeds()
    ply_seeds()
    stl_seeds()
    for t in sorted(CORPUS.iterdir()):
        print(t.name, len(list(t.iterdir())), "files")
