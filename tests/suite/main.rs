//! raypick's integration tests, in one test binary (`cargo test --test suite`; one module's
//! tests: `cargo test --test suite engine::`). One binary links raypick, wgpu, axum and tokio
//! once, where one binary per file linked them 37 times, and its tests share one GPU context.
//! Each module is one concern, as each file was; `common` is the shared plumbing (the GPU
//! context, the equivalence checks).
//!
//! The tests of different modules run side by side in one process: a test never changes the
//! process's state (environment, working folder, global thread pool), and the few that need a
//! fresh process (peak memory, an address-space limit, a lost shared GPU device) run themselves
//! again as a child ([`run_child_test`]).

mod common;

mod asc_reader;
mod build;
mod camera;
mod cli;
mod cli_build;
mod compare;
mod csv_identity;
mod dem;
mod engine;
mod equivalence;
mod gltf;
mod gpu_limits;
mod gpu_pipeline;
mod hostile_args;
mod hostile_files;
mod instances;
mod layout;
mod mesh_formats;
mod modes;
mod names;
mod obj_reader;
mod precision;
mod ray_order;
mod readme_examples;
mod refit;
mod render;
mod rpk;
mod sah;
mod semantics;
mod server;
mod server_edits;
mod server_limits;
mod server_load;
mod terrain_blocks;
mod transforms;
mod watertight;
mod workgroup_size;

/// A fresh path in the temporary folder for `name`, written with `text`: `prefix`, the process,
/// a number of this process's own, and `name`. Tests of one module run side by side, and two
/// that wrote one path in turn had one read the other's file half-written.
pub fn unique_temp_file(prefix: &str, name: &str, text: &str) -> std::path::PathBuf {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let path = std::env::temp_dir().join(format!("{prefix}-{}-{n}-{name}", std::process::id()));
    std::fs::write(&path, text).expect("write a temporary file");
    path
}

/// The name the test harness knows test `name` of module `module` by (`module_path!()` there:
/// `suite::rpk`), for a test that runs another of its module's tests in a child process with
/// `--exact`.
pub fn child_test_name(module: &str, name: &str) -> String {
    let module = module.split_once("::").map_or("", |(_, rest)| rest);
    format!("{module}::{name}")
}

/// Set in the environment of a child test run by [`run_child_test`]: a child test that must
/// have a process of its own returns at once without it (`cargo test -- --include-ignored`
/// runs it beside the others).
pub const CHILD_TEST: &str = "RAYPICK_CHILD_TEST";

/// The longest a child test may run before it is killed and its test fails (a child stuck in a
/// driver would otherwise hold CI until its own time limit).
const CHILD_TEST_LIMIT: std::time::Duration = std::time::Duration::from_secs(600);

/// Runs the ignored test `name` of module `module` (`module_path!()` there) in a child process
/// through `command` (this test binary, perhaps behind `prlimit`, with what environment the
/// child needs); checks that it ran and passed within [`CHILD_TEST_LIMIT`], and returns what
/// it printed.
pub fn run_child_test(mut command: std::process::Command, module: &str, name: &str) -> String {
    use std::io::Read;
    use std::process::Stdio;
    let mut child = command
        .env(CHILD_TEST, "1")
        .args([
            "--exact",
            &child_test_name(module, name),
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run the child test");
    let drain = |mut pipe: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            let _ = pipe.read_to_end(&mut bytes);
            String::from_utf8_lossy(&bytes).into_owned()
        })
    };
    let stdout = drain(Box::new(child.stdout.take().expect("piped stdout")));
    let stderr = drain(Box::new(child.stderr.take().expect("piped stderr")));
    let started = std::time::Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for the child test") {
            break Some(status);
        }
        if started.elapsed() > CHILD_TEST_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    let text = stdout.join().unwrap_or_default() + &stderr.join().unwrap_or_default();
    let Some(status) = status else {
        panic!("{name} ran past {CHILD_TEST_LIMIT:?} and was killed: {text}");
    };
    assert!(status.success(), "{name}: {text}");
    assert!(text.contains("1 passed"), "{name} did not run: {text}");
    text
}
