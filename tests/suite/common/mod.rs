//! Shared test plumbing: one GPU context per test binary, and the equivalence check run against
//! every backend and the oracle.
#![allow(dead_code)]

use raypick::check::compare::{compare_answers, differences};
use raypick::check::oracle::brute_force_every;
use raypick::check::synthetic::{RayKind, mixed_rays};
use raypick::engine::Simd;
use raypick::{
    Answers, BuildOptions, BuiltScene, CpuPicker, GpuContext, GpuPicker, Hit, Intersector, Mode,
    Picker, Query, Ray, ReferencePicker, Scene,
};
use std::sync::{Arc, OnceLock};

/// A cube's twelve faces as the fuzzed files list them, over corners numbered `4x + 2y + z`
/// (each 0 or 1): two triangles per side.
pub const CUBE_FACES: [[u32; 3]; 12] = [
    [0, 1, 3],
    [0, 3, 2],
    [4, 6, 7],
    [4, 7, 5],
    [0, 4, 5],
    [0, 5, 1],
    [2, 3, 7],
    [2, 7, 6],
    [0, 2, 6],
    [0, 6, 4],
    [1, 5, 7],
    [1, 7, 3],
];

/// The GPU for this test binary. GPU tests never pass silently: without an adapter they fail,
/// saying so (install Mesa lavapipe on machines without a GPU).
pub fn gpu() -> &'static GpuContext {
    static CONTEXT: OnceLock<GpuContext> = OnceLock::new();
    CONTEXT.get_or_init(|| {
        let context =
            GpuContext::new().unwrap_or_else(|e| panic!("GPU tests need a GPU adapter: {e}"));
        eprintln!("gpu adapter: {}", context.describe());
        // Evidence for CI that the GPU tests really ran, and on what.
        // The folder is cargo's, made by `cargo test`; a test binary run by hand (on a lent GPU
        // machine, say) may find it missing.
        let folder = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"));
        std::fs::create_dir_all(folder).expect("make the GPU marker's folder");
        std::fs::write(folder.join("gpu-tests-ran"), context.describe())
            .expect("write the GPU marker");
        context
    })
}

/// Every query mode: closest, any, and all hits with lists of `max_hits` entries (short ones
/// overflow).
pub fn every_mode(max_hits: u32) -> [Query; 3] {
    [
        Query::default(),
        Query {
            mode: Mode::Any,
            ..Query::default()
        },
        Query {
            mode: Mode::All,
            max_hits,
            ..Query::default()
        },
    ]
}

/// Closest-hit picks of `rays` with both intersectors on the CPU, the GPU and the brute-force
/// oracle, asserting zero mismatches per ray kind between every pair. Returns the CPU hits of
/// the default (watertight) intersector.
pub fn assert_equivalent(name: &str, built: Arc<BuiltScene>, rays: &[(RayKind, Ray)]) -> Vec<Hit> {
    let mt = Query {
        intersector: Intersector::MollerTrumbore,
        ..Query::default()
    };
    assert_query_equivalent(name, built.clone(), rays, &mt);
    assert_query_equivalent(name, built, rays, &Query::default()).nearest
}

/// Builds `scene` with `options` and checks it over the mixed ray kinds.
pub fn check_scene(
    name: &str,
    scene: Scene,
    options: BuildOptions,
    rays_per_scene: usize,
) -> Vec<Hit> {
    let built = Arc::new(BuiltScene::new(scene, &options).expect("build"));
    let rays = mixed_rays(&built.scene, rays_per_scene, 7);
    assert_equivalent(name, built, &rays)
}

/// Answers `rays` to `query` on the CPU, the GPU and the oracle and asserts zero mismatches per
/// ray kind between every pair. Returns the CPU answers.
pub fn assert_query_equivalent(
    name: &str,
    built: Arc<BuiltScene>,
    rays: &[(RayKind, Ray)],
    query: &Query,
) -> Answers {
    // An instanced scene is judged against its instances baked into world triangles.
    let baked;
    let scene = match built.instances() {
        Some(instances) => {
            baked = instances.baked().expect("bake the instances");
            &baked
        }
        None => {
            built
                .bvh
                .validate()
                .unwrap_or_else(|e| panic!("{name}: invalid tree: {e}"));
            &built.scene
        }
    };
    let plain: Vec<Ray> = rays.iter().map(|(_, r)| *r).collect();
    let cpu = CpuPicker::new(built.clone())
        .query(&plain, query)
        .expect("cpu query");
    let mut gpu_picker = GpuPicker::new(gpu(), built.clone()).expect("gpu picker");
    let gpu_answers = gpu_picker.query(&plain, query).expect("gpu query");
    // The same GPU in steps of a third of the batch, unsorted: closest and any-hit picks then
    // overlap the host's conversion and refinement with the GPU's steps (as a hardware GPU's
    // large batches do), and must give the same bits.
    gpu_picker.set_reorder_from(usize::MAX);
    gpu_picker.set_chunk_rays((plain.len() / 3 + 1) as u32);
    let stepped = gpu_picker.query(&plain, query).expect("gpu query in steps");
    assert_eq!(
        format!("{stepped:?}"),
        format!("{gpu_answers:?}"),
        "{name} {query:?}: the GPU's answers in overlapped steps differ"
    );
    // The engine (on every lane kind this CPU has, the portable ones included) and the GPU give
    // the reference twin's answers bit for bit. (Möller–Trumbore on a GPU that fuses
    // multiply-adds may differ at shared edges; those are checked against the oracle below.)
    let reference = ReferencePicker::new(built.clone())
        .query(&plain, query)
        .expect("reference query");
    // Each lane kind with the walk the tree's size chooses, and AVX2 (or the best there is)
    // with the other walk too.
    let walks = [
        (Simd::Avx2, None),
        (Simd::Sse, None),
        (Simd::Portable, None),
        (Simd::best_available(), Some(true)),
        (Simd::best_available(), Some(false)),
    ];
    for (simd, interleave) in walks {
        if !simd.is_available() {
            continue;
        }
        let mut engine = CpuPicker::new(built.clone());
        engine.set_simd(simd);
        engine.set_interleave(interleave);
        let answers = engine.query(&plain, query).expect("engine query");
        let differ = differences(query.mode, &answers, &reference);
        assert!(
            differ.is_empty(),
            "{name} {query:?}: the engine on {} lanes (interleave {interleave:?}) differs from the reference on {} rays, first {:?}:\n  engine:    {:?}\n  reference: {:?}",
            simd.name(),
            differ.len(),
            plain[differ[0]],
            answers.hits_of(differ[0]),
            reference.hits_of(differ[0])
        );
    }
    if query.intersector == Intersector::Watertight {
        let differ = differences(query.mode, &gpu_answers, &reference);
        assert!(
            differ.is_empty(),
            "{name} {query:?}: the GPU differs from the reference on {} rays, first {:?}",
            differ.len(),
            plain[differ[0]]
        );
    }
    let (oracle, every_hit) = brute_force_every(scene, &plain, query);
    let mut failures = Vec::new();
    // Where the engine and the oracle name the same triangle, they agree on where in it the
    // ray meets it and which way it faces (the comparison below looks at hit, object,
    // triangle and t only; a mirrored instance's winding left as it was passed it).
    if query.mode == Mode::Closest {
        for (i, (a, b)) in cpu.nearest.iter().zip(&oracle.nearest).enumerate() {
            if a.hit && b.hit && (a.object, a.triangle) == (b.object, b.triangle) {
                let close = (a.u - b.u).abs() < 1e-6
                    && (a.v - b.v).abs() < 1e-6
                    && a.normal.dot(b.normal) > 0.999;
                if !close && failures.len() < 3 {
                    failures.push(format!(
                        "{name} {query:?} cpu/oracle u, v, normal: ray {:?}\n  cpu:    {a:?}\n  oracle: {b:?}",
                        plain[i]
                    ));
                }
            }
        }
    }
    for kind in RayKind::ALL {
        let idx: Vec<usize> = (0..rays.len()).filter(|&i| rays[i].0 == kind).collect();
        if idx.is_empty() {
            continue;
        }
        let kind_rays: Vec<Ray> = idx.iter().map(|&i| plain[i]).collect();
        let pick = |a: &Answers| a.subset(&idx);
        let reference = pick(&every_hit);
        for (pair, a, b) in [
            ("cpu/oracle", &cpu, &oracle),
            ("gpu/cpu", &gpu_answers, &cpu),
            ("gpu/oracle", &gpu_answers, &oracle),
        ] {
            let (tally, bad) = compare_answers(
                scene,
                &kind_rays,
                query.mode,
                &pick(a),
                &pick(b),
                Some(&reference),
            );
            eprintln!("{name:>14} {:>13} {pair:>10}: {tally:?}", kind.name());
            for &j in bad.iter().take(3) {
                failures.push(format!(
                    "{name} {query:?} {} {pair}: ray {:?}\n  first:  {:?}\n  second: {:?}",
                    kind.name(),
                    kind_rays[j],
                    pick(a).hits_of(j),
                    pick(b).hits_of(j)
                ));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} mismatches:\n{}",
        failures.len(),
        failures.join("\n")
    );
    cpu
}

/// Starts a server over `built` on an ephemeral loopback port, on a runtime thread of its own
/// until the test binary exits (the server, server-edit and server-limit tests' one way to start
/// one); returns its address.
pub fn serve(
    built: Arc<BuiltScene>,
    backend: raypick::Backend,
    config: raypick::server::ServerConfig,
) -> std::net::SocketAddr {
    let server = raypick::server::Server::new(built, backend, config).expect("the server starts");
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    listener.set_nonblocking(true).expect("nonblocking");
    let addr = listener.local_addr().expect("address");
    std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .expect("runtime");
        runtime.block_on(async move {
            let listener = tokio::net::TcpListener::from_std(listener).expect("listener");
            server.serve(listener).await.expect("serve");
        });
    });
    addr
}

/// Runs the `raypick` binary with `args` (and a runtime folder for the Vulkan loader); returns
/// its exit code (-1 when a signal ended it), standard output and standard error.
pub fn raypick(args: &[&str]) -> (i32, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_raypick"))
        .args(args)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("run raypick");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// An HTTP client for the server tests: 4xx and 5xx answers returned, not errors; no proxy; the
/// whole of each request within `timeout`.
pub fn http_agent(timeout: std::time::Duration) -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .proxy(None)
        .timeout_global(Some(timeout))
        .build()
        .into()
}
