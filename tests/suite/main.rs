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

/// Runs the ignored test `name` of module `module` (`module_path!()` there) in a child process
/// through `command` (this test binary, perhaps behind `prlimit`, with what environment the
/// child needs); checks that it ran and passed, and returns what it printed.
pub fn run_child_test(mut command: std::process::Command, module: &str, name: &str) -> String {
    let out = command
        .env(CHILD_TEST, "1")
        .args([
            "--exact",
            &child_test_name(module, name),
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .output()
        .expect("run the child test");
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{name}: {text}");
    assert!(text.contains("1 passed"), "{name} did not run: {text}");
    text
}
