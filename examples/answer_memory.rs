//! What a library user's picks cost in fresh memory against memory reused: the trace alone,
//! `Picker::pick` (a new 104-byte `Hit` per ray, in memory the OS zeroes as it is first written)
//! and `Picker::query_into` (the last batch's `Answers` written over), timed in interleaved
//! rounds on one mesh and one ray file, with the page faults each takes. This program installs
//! no global allocator (the `raypick` binary and the benches install
//! `raypick::huge_pages::Allocator`, which keeps freed large blocks: their picks are the reused
//! kind).
//!
//! `cargo run --release --example answer_memory -- MESH.obj RAYS.txt [THREADS]`

use raypick::io::obj::load_obj;
use raypick::io::ray_file::load_rays;
use raypick::picker::Tracer;
use raypick::{Answers, BuildOptions, BuiltScene, CpuPicker, Picker, Query, Ray, Scene};
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// Rounds; each runs the three kinds once, in turn.
const ROUNDS: usize = 9;

/// Minor page faults of this process so far (0 where there is no `getrusage`).
#[cfg(not(unix))]
fn minor_faults() -> i64 {
    0
}

/// Minor page faults of this process so far.
#[cfg(unix)]
fn minor_faults() -> i64 {
    // SAFETY: getrusage fills the struct it is given.
    unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_SELF, &mut usage);
        usage.ru_minflt
    }
}

fn main() -> Result<(), raypick::Error> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(mesh), Some(ray_file)) = (args.get(1), args.get(2)) else {
        eprintln!("usage: answer_memory MESH.obj RAYS.txt [THREADS]");
        std::process::exit(2);
    };
    let threads = match args.get(3).map(|t| t.parse::<usize>()) {
        None => rayon::current_num_threads(),
        Some(Ok(t)) if t > 0 => t,
        Some(_) => {
            eprintln!("THREADS: a whole number from 1");
            std::process::exit(2);
        }
    };
    let rays: Vec<Ray> = load_rays(Path::new(ray_file))?
        .into_iter()
        .map(|r| Ray::new(r.origin, r.dir).with_range(0.0, r.tmax.unwrap_or(f64::INFINITY)))
        .collect();
    let scene = Scene::from_meshes([("mesh".to_string(), load_obj(Path::new(mesh))?)])?;
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default())?);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| raypick::Error::Invalid(format!("cannot start {threads} threads: {e}")))?;
    let mut picker = CpuPicker::new(built.clone());
    let query = Query::default();
    let (local, _) = raypick::frame::scene_rays(built.frame(), &rays, &query);
    let settings = built.settings(&query);
    let mut reused = Answers::default();
    let kinds = [
        "trace alone",
        "pick, fresh memory",
        "query_into, reused memory",
    ];
    let mut seconds = vec![Vec::new(); kinds.len()];
    let mut faults = [0i64; 3];
    for _ in 0..ROUNDS {
        for (kind, seconds) in seconds.iter_mut().enumerate() {
            let before = minor_faults();
            let start = Instant::now();
            pool.install(|| -> Result<(), raypick::Error> {
                match kind {
                    0 => drop(picker.trace(&local, &settings)?),
                    1 => drop(picker.pick(&rays)?),
                    _ => picker.query_into(&rays, &query, &mut reused)?,
                }
                Ok(())
            })?;
            seconds.push(start.elapsed().as_secs_f64());
            faults[kind] += minor_faults() - before;
        }
    }
    println!(
        "{} rays, {threads} threads, medians of {ROUNDS} rounds:",
        rays.len()
    );
    for ((kind, seconds), faults) in kinds.iter().zip(&mut seconds).zip(faults) {
        seconds.sort_by(f64::total_cmp);
        let median = seconds[ROUNDS / 2];
        println!(
            "{kind}: {:.1} ms ({:.2} M rays/s), {} page faults a pass",
            median * 1e3,
            rays.len() as f64 / median / 1e6,
            faults / ROUNDS as i64
        );
    }
    Ok(())
}
