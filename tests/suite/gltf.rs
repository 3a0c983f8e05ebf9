//! The glTF 2.0 loader through the public API: small `.gltf`/`.glb` files are written at run time
//! (JSON with base64 `data:` buffers, external `.bin` files, GLB containers) and loaded with
//! `raypick::io::gltf::load_gltf`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::DVec3;
use raypick::io::gltf::load_gltf;
use raypick::{BuildOptions, BuiltScene, CpuPicker, Error, Mesh, Picker, Ray, Scene};
use serde_json::{Value, json};

/// A fresh directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> Self {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let dir =
            std::env::temp_dir().join(format!("raypick-gltf-test-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("create temp dir");
        Self(dir)
    }

    fn write(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let path = self.0.join(name);
        std::fs::write(&path, bytes).expect("write temp file");
        path
    }

    fn write_json(&self, name: &str, doc: &Value) -> PathBuf {
        self.write(name, doc.to_string().as_bytes())
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Standard base64 with padding.
fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = u32::from(b[0]) << 16 | u32::from(b[1]) << 8 | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(char::from(ALPHABET[(n >> (18 - 6 * k) & 63) as usize]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// One binary buffer with its buffer views and accessors, built up piece by piece.
#[derive(Default)]
struct Asset {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Asset {
    /// Appends `bytes` as a buffer view (4-byte aligned); returns its index.
    fn view(&mut self, bytes: &[u8], stride: Option<usize>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut view =
            json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(stride) = stride {
            view["byteStride"] = json!(stride);
        }
        self.bin.extend_from_slice(bytes);
        self.views.push(view);
        self.views.len() - 1
    }

    fn accessor(&mut self, accessor: Value) -> usize {
        self.accessors.push(accessor);
        self.accessors.len() - 1
    }

    /// A FLOAT VEC3 POSITION accessor (with the min/max the spec asks for).
    fn positions(&mut self, points: &[[f32; 3]]) -> usize {
        let bytes: Vec<u8> = points
            .iter()
            .flatten()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let view = self.view(&bytes, None);
        let mut min = [f32::INFINITY; 3];
        let mut max = [f32::NEG_INFINITY; 3];
        for p in points {
            for k in 0..3 {
                min[k] = min[k].min(p[k]);
                max[k] = max[k].max(p[k]);
            }
        }
        let finite = |v: [f32; 3]| v.map(|x| if x.is_finite() { x } else { 0.0 });
        self.accessor(json!({
            "bufferView": view, "componentType": 5126, "count": points.len(), "type": "VEC3",
            "min": finite(min), "max": finite(max)
        }))
    }

    fn indices_u16(&mut self, indices: &[u16]) -> usize {
        let bytes: Vec<u8> = indices.iter().flat_map(|v| v.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        self.accessor(json!({
            "bufferView": view, "componentType": 5123, "count": indices.len(), "type": "SCALAR"
        }))
    }

    fn indices_u32(&mut self, indices: &[u32]) -> usize {
        let bytes: Vec<u8> = indices.iter().flat_map(|v| v.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        self.accessor(json!({
            "bufferView": view, "componentType": 5125, "count": indices.len(), "type": "SCALAR"
        }))
    }

    fn indices_u8(&mut self, indices: &[u8]) -> usize {
        let view = self.view(indices, None);
        self.accessor(json!({
            "bufferView": view, "componentType": 5121, "count": indices.len(), "type": "SCALAR"
        }))
    }

    /// The document: `rest` (meshes, nodes, scenes, ...) plus the buffer, stored at `uri`
    /// (`None`: the GLB BIN chunk).
    fn document(&self, rest: Value, uri: Option<String>) -> Value {
        let mut buffer = json!({"byteLength": self.bin.len()});
        if let Some(uri) = uri {
            buffer["uri"] = json!(uri);
        }
        let mut doc = json!({
            "asset": {"version": "2.0"},
            "buffers": [buffer],
            "bufferViews": self.views,
            "accessors": self.accessors,
        });
        for (key, value) in rest.as_object().expect("an object").clone() {
            doc[key] = value;
        }
        doc
    }

    /// The document with its buffer as a base64 data URI.
    fn gltf(&self, rest: Value) -> Value {
        self.document(
            rest,
            Some(format!(
                "data:application/octet-stream;base64,{}",
                base64(&self.bin)
            )),
        )
    }

    /// The document as a GLB container with the buffer in the BIN chunk.
    fn glb(&self, rest: Value) -> Vec<u8> {
        let mut json = self.document(rest, None).to_string().into_bytes();
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        let mut bin = self.bin.clone();
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let total = 12 + 8 + json.len() + 8 + bin.len();
        let mut out = Vec::with_capacity(total);
        out.extend_from_slice(b"glTF");
        out.extend(2u32.to_le_bytes());
        out.extend((total as u32).to_le_bytes());
        out.extend((json.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend(json);
        out.extend((bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend(bin);
        out
    }
}

const TRIANGLE: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

/// An asset with one indexed triangle (accessor 0: positions, 1: indices) and the JSON of a
/// mesh named "tri" using them.
fn triangle_asset() -> (Asset, Value) {
    let mut asset = Asset::default();
    let positions = asset.positions(&TRIANGLE);
    let indices = asset.indices_u16(&[0, 1, 2]);
    let mesh = json!({"name": "tri", "primitives": [{"attributes": {"POSITION": positions}, "indices": indices}]});
    (asset, mesh)
}

fn dvec(p: [f32; 3]) -> DVec3 {
    DVec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

fn names(objects: &[(String, Mesh)]) -> Vec<&str> {
    objects.iter().map(|(n, _)| n.as_str()).collect()
}

fn parse_message(result: Result<Vec<(String, Mesh)>, Error>) -> String {
    match result {
        Err(Error::Parse { message, .. }) => message,
        Err(other) => panic!("expected a parse error, got {other:?}"),
        Ok(objects) => panic!("expected a parse error, got {} objects", objects.len()),
    }
}

#[test]
fn single_indexed_triangle() {
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let path = dir.write_json(
        "tri.gltf",
        &asset.gltf(json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0})),
    );
    let objects = load_gltf(&path).unwrap();
    assert_eq!(names(&objects), [format!("{}#tri/0", path.display())]);
    assert_eq!(
        objects[0].1,
        Mesh {
            positions: TRIANGLE.map(dvec).to_vec(),
            triangles: vec![[0, 1, 2]],
        }
    );
}

#[test]
fn unnamed_mesh_uses_its_index_and_u8_u32_indices_work() {
    let dir = TempDir::new();
    let mut asset = Asset::default();
    let p = asset.positions(&TRIANGLE);
    let i8 = asset.indices_u8(&[2, 1, 0]);
    let i32 = asset.indices_u32(&[1, 2, 0]);
    let doc = asset.gltf(json!({
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": p}, "indices": i8}]},
            {"name": "", "primitives": [{"attributes": {"POSITION": p}, "indices": i32}]}
        ],
        "nodes": [{"mesh": 0}, {"mesh": 1}],
        "scenes": [{"nodes": [0, 1]}]
    }));
    let path = dir.write_json("unnamed.gltf", &doc);
    let objects = load_gltf(&path).unwrap();
    let file = path.display();
    assert_eq!(
        names(&objects),
        [format!("{file}#0/0"), format!("{file}#1/0")]
    );
    assert_eq!(objects[0].1.triangles, [[2, 1, 0]]);
    assert_eq!(objects[1].1.triangles, [[1, 2, 0]]);
}

#[test]
fn node_hierarchy_composes_parent_times_child_exactly() {
    let dir = TempDir::new();
    let mut asset = Asset::default();
    let points = [[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
    let p = asset.positions(&points);
    let doc = asset.gltf(json!({
        "meshes": [{"name": "m", "primitives": [{"attributes": {"POSITION": p}}]}],
        "nodes": [
            {"children": [1], "translation": [10.0, 0.0, 0.0], "scale": [2.0, 2.0, 2.0]},
            // 180 degrees about z: an exactly representable quaternion.
            {"mesh": 0, "translation": [1.0, 2.0, 3.0], "rotation": [0.0, 0.0, 1.0, 0.0],
             "scale": [2.0, 3.0, 4.0]}
        ],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    }));
    let path = dir.write_json("hierarchy.gltf", &doc);
    let objects = load_gltf(&path).unwrap();
    assert_eq!(names(&objects), [format!("{}#m/0", path.display())]);
    // Child: scale, then rotate, then translate; then the parent's scale and translation.
    // (1,1,1) -> (2,3,4) -> (-2,-3,4) -> (-1,-1,7) -> (-2,-2,14) -> (8,-2,14).
    assert_eq!(
        objects[0].1.positions,
        [
            DVec3::new(8.0, -2.0, 14.0),
            DVec3::new(12.0, 4.0, 6.0),
            DVec3::new(8.0, 4.0, 6.0),
        ]
    );
    assert_eq!(objects[0].1.triangles, [[0, 1, 2]]);
}

#[test]
fn matrix_transform_is_column_major() {
    let dir = TempDir::new();
    let mut asset = Asset::default();
    let p = asset.positions(&[[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]);
    // x -> y, y -> -x (90 degrees about z), then translate by (5, 6, 7).
    let matrix = [
        0.0, 1.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 5.0, 6.0, 7.0, 1.0,
    ];
    let doc = asset.gltf(json!({
        "meshes": [{"primitives": [{"attributes": {"POSITION": p}}]}],
        "nodes": [{"mesh": 0, "matrix": matrix}],
        "scenes": [{"nodes": [0]}]
    }));
    let objects = load_gltf(&dir.write_json("matrix.gltf", &doc)).unwrap();
    assert_eq!(
        objects[0].1.positions,
        [
            DVec3::new(4.0, 7.0, 8.0),
            DVec3::new(5.0, 6.0, 7.0),
            DVec3::new(5.0, 7.0, 7.0),
        ]
    );
}

/// What exporters write and the spec allows stays readable beside the new refusals: an identity
/// translation, rotation and scale beside a matrix, rounding noise in a matrix's last row, and
/// `asset.version` "2".
#[test]
fn a_matrix_with_identity_trs_or_rounding_noise_still_loads() {
    let dir = TempDir::new();
    let mut asset = Asset::default();
    let p = asset.positions(&[[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]);
    let matrix = [
        1.0, 0.0, 0.0, 1e-9, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, -0.0, 5.0, 6.0, 7.0, 1.0,
    ];
    let mut doc = asset.gltf(json!({
        "meshes": [{"primitives": [{"attributes": {"POSITION": p}}]}],
        "nodes": [{"mesh": 0, "matrix": matrix, "translation": [0.0, 0.0, 0.0],
                   "rotation": [0.0, 0.0, 0.0, 1.0], "scale": [1.0, 1.0, 1.0]}],
        "scenes": [{"nodes": [0]}]
    }));
    doc["asset"]["version"] = json!("2");
    let objects = load_gltf(&dir.write_json("exported.gltf", &doc)).unwrap();
    assert_eq!(objects[0].1.positions[1], DVec3::new(5.0, 6.0, 7.0));
}

#[test]
fn quaternion_rotation_turns_counter_clockwise() {
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let doc = asset.gltf(json!({
        "meshes": [mesh],
        "nodes": [{"mesh": 0, "rotation": [0.0, 0.0, h, h]}],
        "scenes": [{"nodes": [0]}]
    }));
    let objects = load_gltf(&dir.write_json("rot.gltf", &doc)).unwrap();
    let expected = [DVec3::ZERO, DVec3::Y, DVec3::NEG_X];
    for (got, want) in objects[0].1.positions.iter().zip(expected) {
        assert!((*got - want).length() < 1e-12, "{got} vs {want}");
    }
}

#[test]
fn one_mesh_used_by_two_nodes_gives_two_objects() {
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let doc = asset.gltf(json!({
        "meshes": [mesh],
        "nodes": [
            {"children": [1, 2]},
            {"mesh": 0},
            {"mesh": 0, "translation": [0.0, 0.0, 5.0]}
        ],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    }));
    let path = dir.write_json("twice.gltf", &doc);
    let objects = load_gltf(&path).unwrap();
    let file = path.display();
    assert_eq!(
        names(&objects),
        [format!("{file}#tri@node1/0"), format!("{file}#tri@node2/0")]
    );
    assert_eq!(objects[0].1.positions, TRIANGLE.map(dvec));
    assert_eq!(
        objects[1].1.positions,
        TRIANGLE.map(|p| dvec(p) + DVec3::new(0.0, 0.0, 5.0))
    );
    assert_eq!(objects[0].1.triangles, objects[1].1.triangles);
}

#[test]
fn triangle_strip_and_fan_follow_the_gltf_rules() {
    let dir = TempDir::new();
    let mut asset = Asset::default();
    let p = asset.positions(&[
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 2.0, 0.0],
    ]);
    let strip = asset.indices_u16(&[0, 1, 2, 3, 4]);
    let doc = asset.gltf(json!({
        "meshes": [{"name": "s", "primitives": [
            {"attributes": {"POSITION": p}, "indices": strip, "mode": 5},
            {"attributes": {"POSITION": p}, "mode": 6}
        ]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}]
    }));
    let path = dir.write_json("strip.gltf", &doc);
    let objects = load_gltf(&path).unwrap();
    let file = path.display();
    assert_eq!(
        names(&objects),
        [format!("{file}#s/0"), format!("{file}#s/1")]
    );
    // Strip: triangle i is (v_i, v_{i+1+i%2}, v_{i+2-i%2}).
    assert_eq!(objects[0].1.triangles, [[0, 1, 2], [1, 3, 2], [2, 3, 4]]);
    // Fan (non-indexed): triangle i is (v_{i+1}, v_{i+2}, v_0).
    assert_eq!(objects[1].1.triangles, [[1, 2, 0], [2, 3, 0], [3, 4, 0]]);
}

#[test]
fn non_indexed_primitive_uses_sequential_vertices() {
    let dir = TempDir::new();
    let mut asset = Asset::default();
    let mut points = TRIANGLE.to_vec();
    points.extend(TRIANGLE.map(|[x, y, z]| [x, y, z + 1.0]));
    let p = asset.positions(&points);
    let doc = asset.gltf(json!({
        "meshes": [{"primitives": [{"attributes": {"POSITION": p}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}]
    }));
    let objects = load_gltf(&dir.write_json("plain.gltf", &doc)).unwrap();
    assert_eq!(objects[0].1.triangles, [[0, 1, 2], [3, 4, 5]]);
    assert_eq!(objects[0].1.positions.len(), 6);
}

#[test]
fn points_and_lines_are_skipped_but_keep_primitive_numbers() {
    let dir = TempDir::new();
    let (mut asset, _) = triangle_asset();
    let line = asset.indices_u16(&[0, 1]);
    let doc = asset.gltf(json!({
        "meshes": [{"name": "mixed", "primitives": [
            {"attributes": {"POSITION": 0}, "mode": 0},
            {"attributes": {"POSITION": 0}, "indices": line, "mode": 1},
            {"attributes": {"POSITION": 0}, "mode": 3},
            {"attributes": {"POSITION": 0}, "indices": 1}
        ]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}]
    }));
    let path = dir.write_json("mixed.gltf", &doc);
    let objects = load_gltf(&path).unwrap();
    assert_eq!(names(&objects), [format!("{}#mixed/3", path.display())]);
}

#[test]
fn glb_gives_the_same_meshes_as_gltf() {
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let rest = json!({
        "meshes": [mesh],
        "nodes": [{"mesh": 0, "translation": [0.5, 0.25, -3.0]}],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    });
    let gltf = dir.write_json("a.gltf", &asset.gltf(rest.clone()));
    let glb = dir.write("a.glb", &asset.glb(rest));
    let from_gltf = load_gltf(&gltf).unwrap();
    let from_glb = load_gltf(&glb).unwrap();
    assert_eq!(names(&from_glb), [format!("{}#tri/0", glb.display())]);
    assert_eq!(from_glb[0].1, from_gltf[0].1);
    assert_eq!(from_glb[0].1.positions[0], DVec3::new(0.5, 0.25, -3.0));
}

#[test]
fn external_bin_file_with_escaped_name() {
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    dir.write("tri data.bin", &asset.bin);
    let doc = asset.document(
        json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}),
        Some("tri%20data.bin".to_owned()),
    );
    let objects = load_gltf(&dir.write_json("ext.gltf", &doc)).unwrap();
    assert_eq!(objects[0].1.positions, TRIANGLE.map(dvec));
}

#[test]
fn interleaved_stride_sparse_values_and_missing_min_max() {
    let dir = TempDir::new();
    let mut asset = Asset::default();
    // Positions interleaved with (unused) normals: 24-byte stride.
    let mut bytes = Vec::new();
    for p in TRIANGLE {
        for v in p.into_iter().chain([0.0, 0.0, 1.0]) {
            bytes.extend(f32::to_le_bytes(v));
        }
    }
    let view = asset.view(&bytes, Some(24));
    let sparse_index = asset.view(&1u16.to_le_bytes(), None);
    let sparse_value: Vec<u8> = [3.0f32, 0.0, 0.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let sparse_value = asset.view(&sparse_value, None);
    let p = asset.accessor(json!({
        "bufferView": view, "componentType": 5126, "count": 3, "type": "VEC3",
        "sparse": {
            "count": 1,
            "indices": {"bufferView": sparse_index, "componentType": 5123},
            "values": {"bufferView": sparse_value}
        }
    }));
    let doc = asset.gltf(json!({
        "meshes": [{"primitives": [{"attributes": {"POSITION": p}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}]
    }));
    let objects = load_gltf(&dir.write_json("sparse.gltf", &doc)).unwrap();
    assert_eq!(
        objects[0].1.positions,
        [DVec3::ZERO, DVec3::new(3.0, 0.0, 0.0), DVec3::Y]
    );
}

#[test]
fn scene_selection_default_all_scenes_or_parentless_nodes() {
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let mut other = mesh.clone();
    other["name"] = json!("other");
    let base = json!({
        "meshes": [mesh, other],
        "nodes": [{"mesh": 0}, {"mesh": 1, "children": [2]}, {"mesh": 0}],
        "scenes": [{"nodes": [0]}, {"nodes": [1]}]
    });
    let load = |name: &str, patch: &dyn Fn(&mut Value)| {
        let mut doc = asset.gltf(base.clone());
        patch(&mut doc);
        let path = dir.write_json(name, &doc);
        let file = path.display().to_string();
        load_gltf(&path)
            .unwrap()
            .into_iter()
            .map(|(n, _)| n.strip_prefix(&file).unwrap().to_owned())
            .collect::<Vec<_>>()
    };
    // The default scene only: node 1, then its child node 2.
    assert_eq!(
        load("default.gltf", &|d| d["scene"] = json!(1)),
        ["#other/0", "#tri/0"]
    );
    // No default: every scene's roots, scene by scene.
    assert_eq!(
        load("all.gltf", &|_| {}),
        ["#tri@node0/0", "#other/0", "#tri@node2/0"]
    );
    // No scenes: the nodes that are nobody's child, in node order.
    assert_eq!(
        load("none.gltf", &|d| {
            d.as_object_mut().unwrap().remove("scenes");
        }),
        ["#tri@node0/0", "#other/0", "#tri@node2/0"]
    );
    // A node in two scenes (no default) is walked in each.
    assert_eq!(
        load("shared.gltf", &|d| d["scenes"] =
            json!([{"nodes": [0]}, {"nodes": [0]}])),
        ["#tri@scene0.node0/0", "#tri@scene1.node0/0"]
    );
}

#[test]
fn picks_report_objects_in_load_order() {
    let dir = TempDir::new();
    let mut asset = Asset::default();
    let p = asset.positions(&[[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]]);
    let doc = asset.gltf(json!({
        "meshes": [{"name": "plate", "primitives": [{"attributes": {"POSITION": p}}]}],
        "nodes": [
            {"mesh": 0},
            {"children": [2], "translation": [0.0, 0.0, 1.0]},
            {"mesh": 0, "translation": [0.0, 0.0, 1.0]}
        ],
        "scenes": [{"nodes": [0, 1]}],
        "scene": 0
    }));
    let path = dir.write_json("pick.gltf", &doc);
    let objects = load_gltf(&path).unwrap();
    let scene = Scene::from_meshes(objects).unwrap();
    let file = path.display();
    let object_names: Vec<&str> = scene.objects().iter().map(|o| o.name.as_str()).collect();
    assert_eq!(
        object_names,
        [
            format!("{file}#plate@node0/0"),
            format!("{file}#plate@node2/0")
        ]
    );
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
    let mut picker = CpuPicker::new(built.clone());
    let hits = picker
        .pick(&[
            Ray::new(DVec3::new(0.0, 0.0, 10.0), DVec3::NEG_Z),
            Ray::new(DVec3::new(0.0, 0.0, -10.0), DVec3::Z),
        ])
        .unwrap();
    // From above, the instance of node 2 (z = 2) is nearest; from below, node 0's (z = 0).
    assert!(hits[0].hit && hits[1].hit);
    assert_eq!((hits[0].object, hits[0].triangle), (1, 0));
    assert_eq!(hits[0].position, DVec3::new(0.0, 0.0, 2.0));
    assert_eq!((hits[1].object, hits[1].triangle), (0, 0));
    assert_eq!(hits[1].position, DVec3::ZERO);
    assert!(
        built.scene.objects()[hits[0].object as usize]
            .name
            .ends_with("@node2/0")
    );
}

#[test]
fn missing_file_is_an_io_error_naming_it() {
    let path = std::env::temp_dir().join("raypick-gltf-test-does-not-exist.gltf");
    match load_gltf(&path) {
        Err(Error::Io { path: p, .. }) => assert_eq!(p, path.display().to_string()),
        other => panic!("expected an I/O error, got {other:?}"),
    }
}

#[test]
fn bad_json_is_a_parse_error_with_a_line() {
    let dir = TempDir::new();
    let path = dir.write(
        "bad.gltf",
        b"{\n  \"asset\": {\"version\": \"2.0\"},\n  \"nodes\": [\n",
    );
    match load_gltf(&path) {
        Err(Error::Parse {
            path: p,
            line,
            message,
        }) => {
            assert_eq!(p, path.display().to_string());
            assert_eq!(line, Some(4));
            assert!(message.contains("JSON"), "{message}");
        }
        other => panic!("expected a parse error, got {other:?}"),
    }
    // Valid JSON that is not a valid glTF document.
    let path = dir.write(
        "invalid.gltf",
        br#"{"asset": {"version": "2.0"}, "scene": 3}"#,
    );
    let message = parse_message(load_gltf(&path));
    assert!(message.contains("invalid glTF: scene"), "{message}");
}

#[test]
fn index_out_of_range_names_mesh_primitive_and_accessor() {
    let dir = TempDir::new();
    let mut asset = Asset::default();
    let p = asset.positions(&TRIANGLE);
    let i = asset.indices_u16(&[0, 1, 3]);
    let doc = asset.gltf(json!({
        "meshes": [{"name": "tri", "primitives": [{"attributes": {"POSITION": p}, "indices": i}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}]
    }));
    let message = parse_message(load_gltf(&dir.write_json("oob.gltf", &doc)));
    assert_eq!(
        message,
        "mesh 0 ('tri') primitive 0: index accessor 1: index 2 is 3, out of range (POSITION has 3 vertices)"
    );
}

#[test]
fn missing_buffer_file_is_an_io_error_naming_both_files() {
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let doc = asset.document(
        json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}),
        Some("missing.bin".to_owned()),
    );
    let path = dir.write_json("nobin.gltf", &doc);
    match load_gltf(&path) {
        Err(e @ Error::Io { .. }) => {
            let Error::Io { path: p, source } = &e else {
                unreachable!()
            };
            assert_eq!(Path::new(p), dir.0.join("missing.bin"));
            assert_eq!(source.kind(), std::io::ErrorKind::NotFound);
            let shown = e.to_string();
            assert!(shown.contains(&path.display().to_string()), "{shown}");
            assert!(shown.contains("buffer 0"), "{shown}");
            assert!(shown.contains("POSITION accessor 0"), "{shown}");
        }
        other => panic!("expected an I/O error, got {other:?}"),
    }
}

#[test]
fn malformed_data_is_a_parse_error_not_a_panic() {
    let dir = TempDir::new();
    let cases: Vec<(&str, Value, &str)> = {
        let mut list = Vec::new();
        // A NaN position.
        let mut asset = Asset::default();
        let p = asset.positions(&[[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        list.push((
            "nan",
            asset.gltf(
                json!({"meshes": [{"primitives": [{"attributes": {"POSITION": p}}]}],
                "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}),
            ),
            "POSITION accessor 0: vertex 1",
        ));
        // An accessor longer than its buffer view.
        let (mut asset, mesh) = triangle_asset();
        asset.accessors[0]["count"] = json!(4);
        list.push((
            "long",
            asset.gltf(
                json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}),
            ),
            "do not fit in bufferView 0",
        ));
        // A buffer view past the end of its buffer.
        let (mut asset, mesh) = triangle_asset();
        asset.views[1]["byteLength"] = json!(600);
        list.push((
            "view",
            asset.gltf(
                json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}),
            ),
            "runs past the end of buffer 0",
        ));
        // A POSITION attribute naming a missing accessor (the gltf crate's own check panics).
        let (asset, _) = triangle_asset();
        list.push((
            "posidx",
            asset.gltf(
                json!({"meshes": [{"primitives": [{"attributes": {"POSITION": 9}}]}],
                "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}),
            ),
            "attribute POSITION uses accessor 9",
        ));
        // A cycle in the node hierarchy.
        let (asset, mesh) = triangle_asset();
        list.push((
            "cycle",
            asset.gltf(
                json!({"meshes": [mesh], "nodes": [{"children": [1]}, {"mesh": 0, "children": [0]}],
                "scenes": [{"nodes": [0]}]}),
            ),
            "node 0 is reached twice",
        ));
        // Positions that are not FLOAT VEC3.
        let (mut asset, mesh) = triangle_asset();
        asset.accessors[0]["type"] = json!("VEC2");
        list.push((
            "vec2",
            asset.gltf(
                json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}),
            ),
            "holds VEC2 FLOAT; only FLOAT VEC3 positions",
        ));
        // A required geometry extension.
        let (asset, mesh) = triangle_asset();
        list.push((
            "draco",
            asset.gltf(
                json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}],
                "extensionsUsed": ["KHR_draco_mesh_compression"],
                "extensionsRequired": ["KHR_draco_mesh_compression"]}),
            ),
            "requires the extension KHR_draco_mesh_compression",
        ));
        // A bad data URI.
        let (asset, mesh) = triangle_asset();
        list.push((
            "uri",
            asset.document(
                json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}),
                Some("data:application/octet-stream;base64,AA!A".to_owned()),
            ),
            "bad data URI",
        ));
        // A zero rotation quaternion.
        let (asset, mesh) = triangle_asset();
        list.push((
            "quat",
            asset.gltf(
                json!({"meshes": [mesh], "nodes": [{"mesh": 0, "rotation": [0.0, 0.0, 0.0, 0.0]}],
                "scenes": [{"nodes": [0]}]}),
            ),
            "node 0: the rotation quaternion is 0 0 0 0",
        ));
        // A world transform that overflows f64 through the hierarchy.
        let (asset, mesh) = triangle_asset();
        let mut nodes: Vec<Value> = (1..12)
            .map(|child| json!({"scale": [1e30, 1e30, 1e30], "children": [child]}))
            .collect();
        nodes.push(json!({"mesh": 0}));
        list.push((
            "overflow",
            asset.gltf(json!({"meshes": [mesh], "nodes": nodes, "scenes": [{"nodes": [0]}]})),
            "the world transform (parent · node) is not finite",
        ));
        // A finite world transform (10¹⁰⁰ on each axis) that sends a vertex past f64's range.
        let mut asset = Asset::default();
        let positions = asset.positions(&[[0.0, 0.0, 0.0], [1e10, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        let mesh = json!({"name": "far", "primitives": [{"attributes": {"POSITION": positions}}]});
        let mut nodes: Vec<Value> = (1..10)
            .map(|child| json!({"scale": [1e30, 1e30, 1e30], "children": [child]}))
            .collect();
        nodes.push(json!({"mesh": 0, "scale": [1e30, 1e30, 1e30]}));
        list.push((
            "vertex_overflow",
            asset.gltf(json!({"meshes": [mesh], "nodes": nodes, "scenes": [{"nodes": [0]}]})),
            "mesh 0 ('far') primitive 0: vertex 1 [10000000000, 0, 0] is not finite after node 9's world transform",
        ));
        // What the spec asks and the crate does not check, which loaded with exit 0 and other
        // geometry: elements closer than their size, a matrix that is not affine, a matrix
        // beside TRS, and a glTF 1.0 file.
        let (mut asset, mesh) = triangle_asset();
        asset.views[0]["byteStride"] = json!(4);
        asset.views[0]["target"] = json!(34962);
        let one = json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]});
        list.push((
            "stride",
            asset.gltf(one.clone()),
            "bufferView 0 has a byteStride of 4, less than its elements' 12 bytes",
        ));
        let (asset, mesh) = triangle_asset();
        let mut projective = [0.0; 16];
        for k in [0, 5, 10, 15] {
            projective[k] = 1.0;
        }
        projective[11] = -1.0;
        list.push((
            "projective",
            asset.gltf(
                json!({"meshes": [mesh], "nodes": [{"mesh": 0, "matrix": projective}],
                "scenes": [{"nodes": [0]}]}),
            ),
            "node 0: the matrix's last row is 0 0 -1 1, not 0 0 0 1",
        ));
        let (asset, mesh) = triangle_asset();
        let identity = [
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ];
        list.push((
            "matrix_and_trs",
            asset.gltf(
                json!({"meshes": [mesh], "nodes": [{"mesh": 0, "matrix": identity, "scale": [2.0, 2.0, 2.0]}],
                "scenes": [{"nodes": [0]}]}),
            ),
            "node 0 has both a matrix and a translation, rotation or scale",
        ));
        let (asset, mesh) = triangle_asset();
        let mut old = asset
            .gltf(json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}));
        old["asset"]["version"] = json!("1.0");
        list.push((
            "version",
            old,
            "asset.version is '1.0': only glTF 2.x files are read",
        ));
        list
    };
    for (name, doc, expected) in cases {
        let path = dir.write_json(&format!("{name}.gltf"), &doc);
        let message = parse_message(load_gltf(&path));
        assert!(message.contains(expected), "{name}: {message}");
    }
}

#[test]
fn malformed_glb_is_a_parse_error() {
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let rest = json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]});
    let good = asset.glb(rest.clone());
    let mut cases: Vec<(&str, Vec<u8>)> = vec![
        ("magic-only", b"glTF".to_vec()),
        ("truncated", good[..good.len() - 10].to_vec()),
    ];
    let mut tiny_length = good.clone();
    tiny_length[8..12].copy_from_slice(&4u32.to_le_bytes());
    cases.push(("tiny-length", tiny_length));
    let mut version = good.clone();
    version[4..8].copy_from_slice(&1u32.to_le_bytes());
    cases.push(("version", version));
    // A .glb whose buffer has a uri-less buffer but no BIN chunk.
    let mut no_bin = good.clone();
    let json_len = u32::from_le_bytes(no_bin[12..16].try_into().unwrap()) as usize;
    no_bin.truncate(20 + json_len);
    let total = no_bin.len() as u32;
    no_bin[8..12].copy_from_slice(&total.to_le_bytes());
    cases.push(("no-bin", no_bin));
    for (name, bytes) in cases {
        let path = dir.write(&format!("{name}.glb"), &bytes);
        let message = parse_message(load_gltf(&path));
        assert!(!message.is_empty(), "{name}");
    }
    assert!(load_gltf(&dir.write("good.glb", &good)).is_ok());
}

#[test]
fn a_mirrored_node_keeps_its_front_faces_front() {
    // The plate faces +z (counter-clockwise from above). Node 1 mirrors it in x and lifts it:
    // glTF then winds its front faces clockwise, so it still faces +z in the world.
    let dir = TempDir::new();
    let mut asset = Asset::default();
    let p = asset.positions(&[[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]]);
    let doc = asset.gltf(json!({
        "meshes": [{"name": "plate", "primitives": [{"attributes": {"POSITION": p}}]}],
        "nodes": [
            {"mesh": 0},
            {"mesh": 0, "translation": [5.0, 0.0, 0.0], "scale": [-1.0, 1.0, 1.0]}
        ],
        "scenes": [{"nodes": [0, 1]}],
        "scene": 0
    }));
    let path = dir.write_json("mirror.gltf", &doc);
    let placed = raypick::io::gltf::load_gltf_placed(&path).unwrap();
    assert_eq!(
        placed.iter().map(|o| o.2).collect::<Vec<_>>(),
        [false, true]
    );
    let scene = raypick::io::scene_files::load_scene(&[raypick::io::scene_files::SceneFile {
        file: path.clone(),
        mask: None,
        transform: None,
    }])
    .unwrap();
    assert!(!scene.objects()[0].mirrored && scene.objects()[1].mirrored);
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
    let rays = [
        Ray::new(DVec3::new(0.2, -0.2, 10.0), DVec3::NEG_Z),
        Ray::new(DVec3::new(4.8, -0.2, 10.0), DVec3::NEG_Z),
    ];
    let from_above = CpuPicker::new(built.clone())
        .query(
            &rays,
            &raypick::Query {
                cull: raypick::Cull::Back,
                ..raypick::Query::default()
            },
        )
        .unwrap()
        .nearest;
    for (k, hit) in from_above.iter().enumerate() {
        assert!(hit.hit, "plate {k}: its front face, seen from above");
        assert_eq!(hit.object, k as u32);
        assert!(hit.normal.z > 0.0, "plate {k}: the normal faces up");
    }
    // u and v weigh the file's second and third vertices on the mirrored plate too.
    let world = [[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]]
        .map(|[x, y, z]| DVec3::new(5.0 - x, y, z));
    let h = &from_above[1];
    let on = world[0] * (1.0 - h.u - h.v) + world[1] * h.u + world[2] * h.v;
    assert!((on - h.position).length() < 1e-12, "{h:?}");
}

#[test]
fn nodes_sharing_a_mesh_load_as_instances_of_it_and_answer_as_the_copies() {
    use raypick::io::scene_files::{Loaded, SceneFile, load_instanced, load_scene};
    use raypick::{BuildOptions, BuiltScene, Cull, Picker, Query, Ray, ReferencePicker};
    use std::sync::Arc;
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let doc = asset.gltf(json!({
        "meshes": [mesh],
        "nodes": [
            {"children": [1, 2, 3]},
            {"mesh": 0},
            {"mesh": 0, "translation": [0.0, 0.0, 5.0], "scale": [2.0, 1.0, 1.0]},
            {"mesh": 0, "translation": [3.0, 0.0, 1.0], "scale": [-1.0, 1.0, 1.0]}
        ],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    }));
    let path = dir.write_json("shared.gltf", &doc);
    let files = [SceneFile {
        file: path.clone(),
        mask: None,
        transform: None,
    }];
    let Loaded::Instanced(meshes, instances) = load_instanced(&files).unwrap() else {
        panic!("a mesh placed three times is instanced");
    };
    assert_eq!(meshes.len(), 1, "the mesh is stored once");
    assert_eq!(instances.len(), 3);
    let copies = load_scene(&files).unwrap();
    let names: Vec<&str> = copies.objects().iter().map(|o| o.name.as_str()).collect();
    let instance_names: Vec<&str> = instances.iter().map(|i| i.name.as_str()).collect();
    assert_eq!(instance_names, names);
    let instanced =
        Arc::new(BuiltScene::instanced(meshes, instances, &BuildOptions::default()).unwrap());
    let copied = Arc::new(BuiltScene::new(copies, &BuildOptions::default()).unwrap());
    // Straight down through each placed triangle, and up from below, culling back faces.
    let rays: Vec<Ray> = [
        (0.2, 0.2, 0.0),
        (0.6, 0.2, 5.0),
        (2.8, 0.2, 1.0),
        (2.2, 0.2, 1.0),
    ]
    .into_iter()
    .flat_map(|(x, y, z)| {
        [
            Ray::new(DVec3::new(x, y, z + 10.0), DVec3::NEG_Z),
            Ray::new(DVec3::new(x, y, z - 10.0), DVec3::Z),
        ]
    })
    .collect();
    for cull in [Cull::None, Cull::Back] {
        let query = Query {
            cull,
            ..Query::default()
        };
        let a = ReferencePicker::new(instanced.clone())
            .query(&rays, &query)
            .unwrap();
        let b = ReferencePicker::new(copied.clone())
            .query(&rays, &query)
            .unwrap();
        for (x, y) in a.nearest.iter().zip(&b.nearest) {
            assert_eq!(
                (x.hit, x.object, x.triangle),
                (y.hit, y.object, y.triangle),
                "{cull:?}"
            );
            if x.hit {
                assert!((x.position - y.position).length() < 1e-12);
                assert!((x.normal - y.normal).length() < 1e-12, "{x:?} {y:?}");
                assert!((x.u - y.u).abs() < 1e-12 && (x.v - y.v).abs() < 1e-12);
            }
        }
        assert!(a.nearest.iter().filter(|h| h.hit).count() >= 3, "{cull:?}");
    }
}

/// Runs `raypick pick -q` on the file (it must succeed); its name as given, and what it wrote
/// on standard error.
fn quiet_pick_stderr(path: &Path) -> (String, String) {
    let name = path.display().to_string();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_raypick"))
        .args(["pick", "--backend", "cpu", "-q", "--scene", &name])
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stderr}");
    (name, stderr)
}

#[test]
fn a_file_that_places_no_triangle_says_so_once() {
    let dir = TempDir::new();
    let (mut asset, mesh) = triangle_asset();
    let line = asset.indices_u16(&[0, 1]);
    let lines_only = json!({"name": "wires", "primitives": [
        {"attributes": {"POSITION": 0}, "mode": 0},
        {"attributes": {"POSITION": 0}, "indices": line, "mode": 1}
    ]});
    for (file, rest, why) in [
        (
            "wires.gltf",
            json!({"meshes": [lines_only], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}),
            "its placed meshes hold only point and line primitives",
        ),
        (
            "unplaced.gltf",
            json!({"meshes": [mesh], "nodes": [{}], "scenes": [{"nodes": [0]}]}),
            "none of its 1 mesh(es) is placed by a node of its scene",
        ),
    ] {
        let path = dir.write_json(file, &asset.gltf(rest));
        let (name, stderr) = quiet_pick_stderr(&path);
        let warning =
            format!("warning: {name}: no triangle is placed ({why}), so it adds no object");
        assert_eq!(stderr.matches(&warning).count(), 1, "{stderr}");
    }
}

#[test]
fn a_description_without_repeats_loads_as_copies_from_one_read_of_each_file() {
    use raypick::io::scene_files::{Loaded, SceneFile, load_instanced, load_scene};
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let listing = |path: &std::path::Path| SceneFile {
        file: path.to_path_buf(),
        mask: None,
        transform: None,
    };
    let once = dir.write_json(
        "once.gltf",
        &asset.gltf(json!({
            "meshes": [mesh.clone()],
            "nodes": [{"mesh": 0, "scale": [-1.0, 1.0, 1.0]}],
            "scenes": [{"nodes": [0]}]
        })),
    );
    let twice = dir.write_json(
        "twice.gltf",
        &asset.gltf(json!({
            "meshes": [mesh],
            "nodes": [{"mesh": 0}, {"mesh": 0, "translation": [0.0, 0.0, 2.0]}],
            "scenes": [{"nodes": [0, 1]}]
        })),
    );
    let names = |scene: &raypick::Scene| -> Vec<String> {
        scene.objects().iter().map(|o| o.name.clone()).collect()
    };
    // Nothing repeats: the scene of copies, the same as `load_scene`'s (the mirrored node's
    // triangle wound back), from the one read of the glTF file.
    let good = dir.write("good.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let plain = [listing(&good), listing(&once)];
    let Loaded::Copies(copies) = load_instanced(&plain).unwrap() else {
        panic!("nothing repeats");
    };
    let direct = load_scene(&plain).unwrap();
    assert_eq!(names(&copies), names(&direct));
    assert_eq!(copies.positions(), direct.positions());
    assert_eq!(copies.triangles(), direct.triangles());
    // An OBJ that cannot be read: its own read says so, whichever way the scene is loaded.
    let bad = dir.write("bad.obj", b"v 0 0 0\nf 1 2 3\n");
    let Err(error) = load_instanced(&[listing(&bad), listing(&once)]) else {
        panic!("the bad OBJ is read");
    };
    assert!(error.to_string().contains("bad.obj"), "{error}");
    assert!(load_scene(&[listing(&bad), listing(&once)]).is_err());
    // A glTF whose nodes share a mesh: everything is read, in the listing's order.
    let Err(error) = load_instanced(&[listing(&bad), listing(&twice)]) else {
        panic!("the OBJ is read once something repeats");
    };
    let message = error.to_string();
    assert!(message.contains("bad.obj"), "{message}");
    let files = [listing(&good), listing(&twice), listing(&once)];
    let Loaded::Instanced(meshes, instances) = load_instanced(&files).unwrap() else {
        panic!("instanced");
    };
    // The OBJ's mesh first, then each glTF's, as read in order.
    assert_eq!(meshes.len(), 3);
    assert_eq!(meshes[0].objects()[0].name, good.display().to_string());
    let used: Vec<u32> = instances.iter().map(|i| i.mesh).collect();
    assert_eq!(used, [0, 1, 1, 2]);
    let copies = load_scene(&files).unwrap();
    let instance_names: Vec<String> = instances.iter().map(|i| i.name.clone()).collect();
    assert_eq!(instance_names, names(&copies));
}

/// Node transforms keep the JSON's f64 numbers (issue 15: instances 10⁶ m out pick within
/// 1 mm): the `gltf` crate reads them as f32, which put these nodes up to 6 cm off. Both the
/// copies and the instances of a shared mesh are where the file says, and picks on both land
/// on the exact point.
#[test]
fn node_transforms_far_from_the_origin_keep_their_millimetres() {
    use raypick::io::scene_files::{Loaded, SceneFile, load_instanced, load_scene};
    use raypick::{Query, ReferencePicker};
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let far = [1_000_000.123_456, 2_000_000.654_321, 3_000.000_7];
    let other = [-1_000_000.031_25, 2_000_000.001, 0.000_3];
    // A rotation by 90° about z written as a matrix, placed far out.
    let matrix = [
        0.0,
        1.0,
        0.0,
        0.0,
        -1.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        1.0,
        0.0,
        999_999.987_654,
        -4.003,
        0.5,
        1.0,
    ];
    let doc = asset.gltf(json!({
        "meshes": [mesh],
        "nodes": [
            {"mesh": 0, "translation": far},
            {"mesh": 0, "translation": other, "scale": [1.000_000_1, 1.0, 1.0]},
            {"mesh": 0, "matrix": matrix}
        ],
        "scenes": [{"nodes": [0, 1, 2]}]
    }));
    let path = dir.write_json("far.gltf", &doc);
    let objects = load_gltf(&path).unwrap();
    let t = |p: [f64; 3]| DVec3::from_array(p);
    assert_eq!(objects[0].1.positions[1], t(far) + DVec3::X);
    assert_eq!(
        objects[1].1.positions[1],
        t(other) + DVec3::new(1.000_000_1, 0.0, 0.0)
    );
    assert_eq!(
        objects[2].1.positions[1],
        DVec3::new(999_999.987_654, -4.003 + 1.0, 0.5)
    );
    // Straight down onto each placed triangle at local (0.25, 0.25), on the instances and on
    // the copies.
    let files = [SceneFile {
        file: path,
        mask: None,
        transform: None,
    }];
    let Loaded::Instanced(meshes, instances) = load_instanced(&files).unwrap() else {
        panic!("a mesh placed three times is instanced");
    };
    let points = [
        t(far) + DVec3::new(0.25, 0.25, 0.0),
        t(other) + DVec3::new(0.25 * 1.000_000_1, 0.25, 0.0),
        DVec3::new(999_999.987_654 - 0.25, -4.003 + 0.25, 0.5),
    ];
    let rays: Vec<Ray> = points
        .iter()
        .map(|p| Ray::new(*p + DVec3::new(0.0, 0.0, 10.0), DVec3::NEG_Z))
        .collect();
    let built = [
        BuiltScene::instanced(meshes, instances, &BuildOptions::default()).unwrap(),
        BuiltScene::new(load_scene(&files).unwrap(), &BuildOptions::default()).unwrap(),
    ];
    for scene in built {
        let answers = ReferencePicker::new(Arc::new(scene))
            .query(&rays, &Query::default())
            .unwrap();
        for (k, (hit, want)) in answers.nearest.iter().zip(points).enumerate() {
            assert!(hit.hit && hit.object == k as u32, "ray {k}: {hit:?}");
            let off = (hit.position - want).length();
            assert!(
                off < 1e-6,
                "ray {k}: {} is {off} m from {want}",
                hit.position
            );
        }
    }
}

/// Strips and fans of fewer than 3 vertices give an object with no triangle: kept (ids stay
/// aligned with the file), and said once on standard error, as an OBJ file's short faces are.
#[test]
fn primitives_too_short_for_a_triangle_are_kept_and_said_once() {
    let dir = TempDir::new();
    let (mut asset, _) = triangle_asset();
    let two = asset.indices_u16(&[0, 1]);
    let mesh = json!({"name": "short", "primitives": [
        {"attributes": {"POSITION": 0}, "indices": 1},
        {"attributes": {"POSITION": 0}, "indices": two, "mode": 5},
        {"attributes": {"POSITION": 0}, "indices": two, "mode": 6}
    ]});
    let path = dir.write_json(
        "short.gltf",
        &asset.gltf(json!({"meshes": [mesh], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]})),
    );
    let objects = load_gltf(&path).unwrap();
    let triangles: Vec<usize> = objects.iter().map(|(_, m)| m.triangles.len()).collect();
    assert_eq!(triangles, [1, 0, 0]);
    let (name, stderr) = quiet_pick_stderr(&path);
    let warning = format!(
        "warning: {name}: 2 triangle primitive(s) give no triangle (too few vertices; the first: \
         mesh 0 ('short') primitive 1), so their objects cannot be hit"
    );
    assert_eq!(stderr.matches(&warning).count(), 1, "{stderr}");
    assert_eq!(stderr.matches("warning").count(), 1, "{stderr}");
}

/// A child's matrix with rounding noise in its last row (w = 1.0000009, within what validation
/// lets through) under a parent 10⁶ out: the noise was composed, and the child moved 0.9 units.
/// The last row is made 0 0 0 1 now, as a root's already was. A rotation quaternion of tiny
/// components (1e-170: its length underflowed) is normalised, not refused as "zero length".
#[test]
fn a_matrix_rows_noise_and_tiny_quaternions_place_nodes_where_they_mean() {
    let dir = TempDir::new();
    let (asset, mesh) = triangle_asset();
    let parent = [
        1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1e6, 0.0, 0.0, 1.0,
    ];
    let noisy = [
        1.0,
        0.0,
        0.0,
        4e-7,
        0.0,
        1.0,
        0.0,
        -3e-7,
        0.0,
        0.0,
        1.0,
        2e-7,
        0.0,
        0.0,
        0.0,
        1.000_000_9,
    ];
    let h = std::f64::consts::FRAC_1_SQRT_2 * 1e-170;
    let doc = asset.gltf(json!({
        "meshes": [mesh],
        "nodes": [
            {"matrix": parent, "children": [1]},
            {"mesh": 0, "matrix": noisy},
            {"mesh": 0, "rotation": [0.0, 0.0, h, h], "translation": [0.0, 0.0, 5.0]}
        ],
        "scenes": [{"nodes": [0, 2]}]
    }));
    let objects = load_gltf(&dir.write_json("noise.gltf", &doc)).unwrap();
    let placed: Vec<DVec3> = TRIANGLE
        .iter()
        .map(|&p| dvec(p) + DVec3::new(1e6, 0.0, 0.0))
        .collect();
    assert_eq!(objects[0].1.positions, placed);
    let turned = [
        DVec3::new(0.0, 0.0, 5.0),
        DVec3::new(0.0, 1.0, 5.0),
        DVec3::new(-1.0, 0.0, 5.0),
    ];
    for (got, want) in objects[1].1.positions.iter().zip(turned) {
        assert!((*got - want).length() < 1e-12, "{got} vs {want}");
    }
}

/// A file of `nodes` nodes each placing a mesh of `primitives` primitives whose POSITION
/// accessor holds no vertex.
fn empty_primitives_placed(nodes: usize, primitives: usize) -> Value {
    let primitive = json!({"attributes": {"POSITION": 0}});
    json!({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": 12, "uri": format!("data:application/octet-stream;base64,{}", base64(&[0; 12]))}],
        "bufferViews": [{"buffer": 0, "byteLength": 12}],
        "accessors": [{"componentType": 5126, "count": 0, "type": "VEC3", "bufferView": 0}],
        "meshes": [{"primitives": vec![primitive; primitives]}],
        "nodes": vec![json!({"mesh": 0}); nodes],
        "scenes": [{"nodes": (0..nodes).collect::<Vec<_>>()}],
        "scene": 0
    })
}

/// Found by a review: the objects a file places were counted against no limit, only their
/// vertices and triangles, so primitives of no vertex placed by many nodes cost their records
/// and names unchecked: 3,000 nodes × 3,000 such primitives (a 137 KB file) aborted the
/// process asking for 2.8 GB, and 1,000 × 1,000 (45 KB) took 676 MB past a 64 MiB budget.
/// Objects now count with the vertices and triangles, and their memory with the budget.
#[test]
fn objects_placed_without_triangles_count_against_the_limits() {
    let dir = TempDir::new();
    let run = |path: &Path, budget: &str| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_raypick"))
            .args([
                "--max-memory",
                budget,
                "pick",
                "--backend",
                "cpu",
                "-q",
                "--scene",
            ])
            .arg(path)
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let many = dir.write_json("many.gltf", &empty_primitives_placed(3000, 3000));
    let (code, err) = run(&many, "8G");
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("places 9000000 objects with 0 vertices and 0 triangles")
            && err.contains("vertices, triangles and objects"),
        "{err}"
    );
    let million = dir.write_json("million.gltf", &empty_primitives_placed(1000, 1000));
    let (code, err) = run(&million, "64M");
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("1000000 objects") && err.contains("memory budget"),
        "{err}"
    );
    // A few such placements load, each an object of no triangle.
    let few = dir.write_json("few.gltf", &empty_primitives_placed(3, 2));
    let (code, err) = run(&few, "64M");
    assert_eq!(code, Some(0), "{err}");
}

/// A strided buffer view needs room for its last element alone after the last stride, not for
/// a whole stride: positions interleaved after normals (the accessor's byteOffset 12, ending
/// with the view) and a view whose last stride's unused bytes are left off both load, with the
/// positions they hold.
#[test]
fn a_strided_view_needs_room_for_its_last_element_only() {
    let dir = TempDir::new();
    for (offset, cut) in [(12usize, 0usize), (0, 12)] {
        let mut asset = Asset::default();
        let mut bytes = Vec::new();
        for p in TRIANGLE {
            let normal = [0.0f32, 0.0, 1.0];
            let (first, second) = if offset == 0 {
                (p, normal)
            } else {
                (normal, p)
            };
            for v in first.into_iter().chain(second) {
                bytes.extend(f32::to_le_bytes(v));
            }
        }
        bytes.truncate(bytes.len() - cut);
        let view = asset.view(&bytes, Some(24));
        let p = asset.accessor(json!({
            "bufferView": view, "byteOffset": offset, "componentType": 5126, "count": 3,
            "type": "VEC3", "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]
        }));
        let doc = asset.gltf(json!({
            "meshes": [{"primitives": [{"attributes": {"POSITION": p}}]}],
            "nodes": [{"mesh": 0}],
            "scenes": [{"nodes": [0]}]
        }));
        let file = dir.write_json(&format!("strided-{offset}.gltf"), &doc);
        let objects = load_gltf(&file).unwrap_or_else(|e| panic!("offset {offset}: {e}"));
        assert_eq!(
            objects[0].1.positions,
            TRIANGLE.map(dvec),
            "offset {offset}"
        );
    }
}
