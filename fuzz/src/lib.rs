//! Helpers shared by the fuzz targets in `fuzz_targets/`.
//!
//! Besides "no panic", the targets check the guarantees the loaders document
//! for a successful result (see `ElevationGrid` and `Mesh`); a failed check
//! panics, so libFuzzer reports it like any other crash.

use std::path::PathBuf;

use raypick::Mesh;
use raypick::dem::ElevationGrid;

/// Asserts what `ElevationGrid`'s docs say every loader guarantees:
/// `dx > 0`, `dy > 0`, finite origin, `heights.len() == ncols * nrows`
/// and finite `Some` heights.
pub fn check_grid(grid: &ElevationGrid) {
    assert!(grid.ncols > 0 && grid.nrows > 0, "empty grid accepted");
    assert!(grid.dx > 0.0 && grid.dy > 0.0, "non-positive spacing");
    assert!(
        grid.dx.is_finite() && grid.dy.is_finite(),
        "non-finite spacing"
    );
    assert!(
        grid.x0.is_finite() && grid.y0.is_finite(),
        "non-finite origin"
    );
    assert_eq!(
        Some(grid.heights.len()),
        grid.ncols.checked_mul(grid.nrows),
        "heights.len() != ncols * nrows"
    );
    assert!(
        grid.heights.iter().flatten().all(|h| h.is_finite()),
        "non-finite Some height"
    );
}

/// A one-line description of a grid for [`debug`].
pub fn grid_summary(grid: &ElevationGrid) -> String {
    let nodata = grid.heights.iter().filter(|h| h.is_none()).count();
    format!(
        "{}x{} grid at ({}, {}) spacing ({}, {}), {nodata} nodata",
        grid.ncols, grid.nrows, grid.x0, grid.y0, grid.dx, grid.dy
    )
}

/// Asserts that every triangle of a loaded mesh indexes an existing vertex
/// and that every position is finite (what `load_obj` promises).
pub fn check_mesh(mesh: &Mesh) {
    let n = mesh.positions.len();
    for t in &mesh.triangles {
        for &i in t {
            assert!((i as usize) < n, "triangle index {i} >= {n} vertices");
        }
    }
    assert!(
        mesh.positions.iter().all(|p| p.is_finite()),
        "non-finite vertex position"
    );
}

/// The body of the mesh-file targets (`obj`, `ply`, `stl`): writes `data` to this process's
/// scratch file with `extension`, loads it with `load`, and checks a mesh that loads.
pub fn load_mesh_file(
    extension: &str,
    data: &[u8],
    load: fn(&std::path::Path) -> Result<Mesh, raypick::Error>,
) {
    // One target per process, so one scratch file.
    static PATH: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    let path = PATH.get_or_init(|| scratch_path(extension));
    std::fs::write(path, data).expect("write scratch file");
    let result = load(path);
    debug(&result, |m: &Mesh| {
        format!(
            "{} vertices, {} triangles",
            m.positions.len(),
            m.triangles.len()
        )
    });
    if let Ok(mesh) = result {
        check_mesh(&mesh);
    }
}

/// When `RAYPICK_FUZZ_DEBUG` is set, prints what the loader returned (the
/// error message, or the size of the result) to stderr; useful with
/// `cargo fuzz run <target> <file>` to see why an input is rejected.
pub fn debug<T, E: std::fmt::Display>(result: &Result<T, E>, size: impl Fn(&T) -> String) {
    static ON: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    if *ON.get_or_init(|| std::env::var_os("RAYPICK_FUZZ_DEBUG").is_some()) {
        match result {
            Ok(value) => eprintln!("raypick-fuzz: Ok({})", size(value)),
            Err(e) => eprintln!("raypick-fuzz: Err({e})"),
        }
    }
}

/// A per-process scratch file for targets whose loader only takes a path
/// (`load_obj`). Prefers `/dev/shm` (tmpfs) to keep the per-run write cheap.
pub fn scratch_path(extension: &str) -> PathBuf {
    let dir = std::env::var_os("RAYPICK_FUZZ_TMPDIR")
        .map(PathBuf::from)
        .or_else(|| {
            let shm = PathBuf::from("/dev/shm");
            shm.is_dir().then_some(shm)
        })
        .unwrap_or_else(std::env::temp_dir);
    dir.join(format!("raypick-fuzz-{}.{extension}", std::process::id()))
}

/// A per-process scratch folder for targets that load a file together with
/// the files it names (`load_gltf`'s buffers, a scene description's files):
/// `<tmp>/raypick-fuzz-<tag>-<pid>/`, created once with small valid files the
/// fuzzed input can refer to by relative path:
///
/// - `tri.bin`: three FLOAT VEC3 positions (36 bytes) then the UNSIGNED_SHORT
///   indices 0, 1, 2 (6 bytes, padded to 8), 44 bytes in all;
/// - `tri.obj`: one triangle; `grid.asc`: a 3 × 3 ESRI ASCII grid with a
///   NODATA cell; `tri.gltf`: a triangle whose buffer is `tri.bin`;
/// - `sub/tri.bin`: a copy of `tri.bin` one folder down.
///
/// Nothing outside the folder is created or named. The folder stays behind
/// when the process exits.
pub fn scratch_dir(tag: &str) -> PathBuf {
    let base = std::env::var_os("RAYPICK_FUZZ_TMPDIR")
        .map(PathBuf::from)
        .or_else(|| {
            let shm = PathBuf::from("/dev/shm");
            shm.is_dir().then_some(shm)
        })
        .unwrap_or_else(std::env::temp_dir);
    let dir = base.join(format!("raypick-fuzz-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("sub")).expect("create the scratch folder");
    let mut bin: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    bin.extend([0u16, 1, 2, 0].iter().flat_map(|v| v.to_le_bytes()));
    let files: [(&str, &[u8]); 5] = [
        ("tri.bin", &bin),
        ("sub/tri.bin", &bin),
        ("tri.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
        (
            "grid.asc",
            b"ncols 3\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 1\nNODATA_value -9999\n1 2 3\n4 -9999 6\n7 8 9\n",
        ),
        ("tri.gltf", TRI_GLTF.as_bytes()),
    ];
    for (name, bytes) in files {
        std::fs::write(dir.join(name), bytes).expect("write a scratch fixture");
    }
    dir
}

/// A triangle (indexed) whose buffer is `tri.bin` (see [`scratch_dir`]).
pub const TRI_GLTF: &str = r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
"nodes":[{"mesh":0,"translation":[1,2,3]}],
"meshes":[{"name":"tri","primitives":[{"attributes":{"POSITION":0},"indices":1}]}],
"buffers":[{"byteLength":44,"uri":"tri.bin"}],
"bufferViews":[{"buffer":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":6}],
"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"},
{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}]}"#;

/// CRC-32 (ISO-HDLC, as used by PNG chunks).
fn crc32(bytes: &[u8]) -> u32 {
    static TABLE: std::sync::OnceLock<[u32; 256]> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        let mut t = [0u32; 256];
        for (n, slot) in t.iter_mut().enumerate() {
            let mut c = n as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    0xedb8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
            *slot = c;
        }
        t
    });
    !bytes.iter().fold(!0u32, |c, &b| {
        table[((c ^ u32::from(b)) & 0xff) as usize] ^ (c >> 8)
    })
}

/// Rewrites the CRC of every complete chunk of a PNG stream in place, so that
/// mutations of chunk contents are not all rejected by the CRC check and the
/// fuzzer reaches the decoder proper. Stops at the first chunk that does not
/// fit in `data` (the rest is left as is, truncated files stay truncated).
pub fn fix_png_crcs(data: &mut [u8]) {
    let mut pos = 8; // PNG signature
    while let Some(header) = data.get(pos..pos + 8) {
        let len = u32::from_be_bytes([header[0], header[1], header[2], header[3]]) as usize;
        let Some(crc_at) = pos.checked_add(8).and_then(|p| p.checked_add(len)) else {
            return;
        };
        if crc_at + 4 > data.len() {
            return;
        }
        let crc = crc32(&data[pos + 4..crc_at]);
        data[crc_at..crc_at + 4].copy_from_slice(&crc.to_be_bytes());
        pos = crc_at + 4;
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn crc_of_iend() {
        assert_eq!(super::crc32(b"IEND"), 0xae42_6082);
    }
}
