#!/usr/bin/env python3
"""Writes the hostile corpus of tests/suite/hostile_files.rs into this folder (standard library only).

Each file is small (under 100 KB) and named for what it tries; README.md lists them. Run it from
anywhere: `python3 tests/data/hostile/make_corpus.py`. The output is deterministic.
"""

import base64
import json
import os
import struct
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))


def write(name, data):
    if isinstance(data, str):
        data = data.encode()
    assert len(data) < 100_000, (name, len(data))
    with open(os.path.join(HERE, name), "wb") as f:
        f.write(data)


# --- GeoTIFF -------------------------------------------------------------------------------

SHORT, LONG, DOUBLE = 3, 4, 12


def tiff(width, height, bits, compression, rows_per_strip, offsets, counts, payload):
    """A little-endian single-band GeoTIFF: header, payload at byte 8, then the IFD and its
    out-of-line values. `offsets` are relative to the payload start unless given as ('abs', n)."""
    payload_at = 8
    abs_offsets = [o[1] if isinstance(o, tuple) else payload_at + o for o in offsets]
    entries = [
        (256, LONG, [width]),
        (257, LONG, [height]),
        (258, SHORT, [bits]),
        (259, SHORT, [compression]),
        (262, SHORT, [1]),
        (273, LONG, abs_offsets),
        (277, SHORT, [1]),
        (278, LONG, [rows_per_strip]),
        (279, LONG, counts),
        (339, SHORT, [1]),
        (33550, DOUBLE, [30.0, 30.0, 0.0]),
        (33922, DOUBLE, [0.0, 0.0, 0.0, 500000.0, 4000000.0, 0.0]),
    ]
    ifd_at = payload_at + len(payload)
    ifd_at += ifd_at % 2
    ifd_size = 2 + 12 * len(entries) + 4
    extra_at = ifd_at + ifd_size
    ifd = struct.pack("<H", len(entries))
    extra = b""
    for tag, kind, values in entries:
        fmt = {SHORT: "H", LONG: "I", DOUBLE: "d"}[kind]
        raw = struct.pack("<" + fmt * len(values), *values)
        if len(raw) <= 4:
            field = raw.ljust(4, b"\0")
        else:
            field = struct.pack("<I", extra_at + len(extra))
            extra += raw
        ifd += struct.pack("<HHI", tag, kind, len(values)) + field
    ifd += struct.pack("<I", 0)
    head = b"II*\0" + struct.pack("<I", ifd_at)
    body = payload + b"\0" * (ifd_at - payload_at - len(payload))
    return head + body + ifd + extra


# A 46340 x 46340 UInt16 header (4.29 GB of samples, just under 2^32 bytes) whose single strip
# claims 4,294,851,200 bytes after the end of a 254-byte-ish file.
write(
    "tiff-46340x46340-header-without-data.tif",
    tiff(46340, 46340, 16, 1, 46340, [("abs", 8)], [46340 * 46340 * 2], b""),
)

# 1 KB of DEFLATE zeros (1 MiB once inflated), repeated by 1,800 strips that all point at it:
# a 16384 x 115200 UInt8 raster (1.9 GB) from a 16 KB file.
strip = zlib.compress(b"\0" * (16384 * 64), 9)
n = 1800
write(
    "tiff-deflate-zeros-1800-strips-share-1kb.tif",
    tiff(16384, 64 * n, 8, 8, 64, [0] * n, [len(strip)] * n, strip),
)

# An honest DEFLATE stream of 64 MB of zeros in a 62 KB file: every strip has its own bytes and
# DEFLATE can expand that much, but 64 million samples from 62 KB is a decompression bomb.
rows = 8000
rps = 1000
stream = zlib.compress(b"\0" * (8000 * rps), 9)
payload = stream * (rows // rps)
write(
    "tiff-deflate-zeros-8000x8000-in-62kb.tif",
    tiff(
        8000,
        rows,
        8,
        8,
        rps,
        [k * len(stream) for k in range(rows // rps)],
        [len(stream)] * (rows // rps),
        payload,
    ),
)

# A 16 x 16 UInt8 raster: strip 0 is present, strip 1 points 1 GB past the end of the file.
write(
    "tiff-strip-offset-past-end-of-file.tif",
    tiff(16, 16, 8, 1, 8, [0, ("abs", 1 << 30)], [128, 128], bytes(range(128)) + b"\0" * 200),
)


# --- PNG ---------------------------------------------------------------------------------


def chunk(kind, data):
    return (
        struct.pack(">I", len(data))
        + kind
        + data
        + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    )


def png(width, height, depth, rows=None):
    out = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, depth, 0, 0, 0, 0))
    if rows is not None:
        out += chunk(b"IDAT", rows) + chunk(b"IEND", b"")
    return out


# An IHDR claiming 65536 x 32768 16-bit pixels (4 GiB) and nothing else.
write("png-ihdr-only-65536x32768.png", png(65536, 32768, 16))

# 8000 x 8000 zero pixels (64 MB) deflated into 62 KB.
write(
    "png-deflate-zeros-8000x8000-in-62kb.png",
    png(8000, 8000, 8, zlib.compress(b"\0" * (8001 * 8000), 9)),
)


# --- glTF --------------------------------------------------------------------------------


def data_uri(raw):
    return "data:application/octet-stream;base64," + base64.b64encode(raw).decode()


def gltf(doc):
    doc = dict(doc)
    doc["asset"] = {"version": "2.0"}
    return json.dumps(doc, separators=(",", ":"))


def zero_filled(meshes, count=16777215, places=1):
    """`meshes` meshes, each with a POSITION accessor of `count` zeros (no bufferView) and one
    sparse value; the first mesh is placed by `places` nodes, each other mesh by one node."""
    raw = struct.pack("<I", 0) + struct.pack("<fff", 1.0, 2.0, 3.0)
    accessors = [
        {
            "componentType": 5126,
            "count": count,
            "type": "VEC3",
            "sparse": {
                "count": 1,
                "indices": {"bufferView": 0, "componentType": 5125},
                "values": {"bufferView": 1},
            },
        }
        for _ in range(meshes)
    ]
    nodes = [{"mesh": 0} for _ in range(places)] + [{"mesh": m} for m in range(1, meshes)]
    return gltf(
        {
            "buffers": [{"byteLength": len(raw), "uri": data_uri(raw)}],
            "bufferViews": [
                {"buffer": 0, "byteLength": 4},
                {"buffer": 0, "byteOffset": 4, "byteLength": 12},
            ],
            "accessors": accessors,
            "meshes": [{"primitives": [{"attributes": {"POSITION": m}}]} for m in range(meshes)],
            "nodes": nodes,
            "scenes": [{"nodes": list(range(len(nodes)))}],
            "scene": 0,
        }
    )


write("gltf-sparse-zero-filled-16M-vertices.gltf", zero_filled(1))
write("gltf-sparse-zero-filled-8-meshes.gltf", zero_filled(8))
write("gltf-sparse-zero-filled-32-meshes.gltf", zero_filled(32))
# 1,048,575 zero-filled vertices (12 MB, allowed) placed by 1,000 nodes: a billion vertices.
write(
    "gltf-zero-filled-1M-vertices-placed-1000-times.gltf",
    zero_filled(1, count=1048575, places=1000),
)

# 350 POSITION accessors that all read the same 48 KB bufferView of an external buffer.
vertices = 4095
raw = b"".join(struct.pack("<fff", i, i % 7, 0.0) for i in range(vertices))
write("gltf-accessors-sharing-one-view.bin", raw)
write(
    "gltf-accessors-sharing-one-view.gltf",
    gltf(
        {
            "buffers": [{"byteLength": len(raw), "uri": "gltf-accessors-sharing-one-view.bin"}],
            "bufferViews": [{"buffer": 0, "byteLength": len(raw)}],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": vertices, "type": "VEC3"}
                for _ in range(350)
            ],
            "meshes": [
                {"primitives": [{"attributes": {"POSITION": k}} for k in range(350)]}
            ],
            "nodes": [{"mesh": 0}],
            "scenes": [{"nodes": [0]}],
        }
    ),
)


def triangle_with_uri(uri, length=36):
    return gltf(
        {
            "buffers": [{"byteLength": length, "uri": uri}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"}
            ],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "nodes": [{"mesh": 0}],
            "scenes": [{"nodes": [0]}],
        }
    )


write("gltf-uri-absolute-etc-passwd.gltf", triangle_with_uri("/etc/passwd"))
write("gltf-uri-dotdot-etc-passwd.gltf", triangle_with_uri("../" * 16 + "etc/passwd"))
write(
    "gltf-uri-percent-encoded-dotdot.gltf",
    triangle_with_uri("%2e%2e/" * 16 + "etc/passwd"),
)
write("gltf-uri-dev-zero.gltf", triangle_with_uri("/dev/zero", length=1 << 30))
write("gltf-uri-file-scheme.gltf", triangle_with_uri("file:///etc/passwd"))
# "sub/../x" would stay inside the folder, but ".." is refused whatever follows it.
write("gltf-uri-dotdot-back-inside.gltf", triangle_with_uri("sub/../gltf-accessors-sharing-one-view.bin"))


def glb(doc, bin_chunk=None):
    body = gltf(doc).encode()
    body += b" " * (-len(body) % 4)
    chunks = struct.pack("<I", len(body)) + b"JSON" + body
    if bin_chunk is not None:
        bin_chunk += b"\0" * (-len(bin_chunk) % 4)
        chunks += struct.pack("<I", len(bin_chunk)) + b"BIN\0" + bin_chunk
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


write(
    "glb-uri-dotdot-etc-passwd.glb",
    glb(json.loads(triangle_with_uri("../../../../../../../../etc/passwd"))),
)


# --- scene descriptions --------------------------------------------------------------------

write("scenes-absolute-etc-passwd.json", json.dumps({"objects": [{"file": "/etc/passwd"}]}))
write(
    "scenes-dotdot.json",
    json.dumps({"objects": [{"file": "../jacksboro_fault_dem_utm.asc"}]}),
)
write("scenes-dev-zero.json", json.dumps({"objects": [{"file": "/dev/zero"}]}))
