//! The `raypick` command line. `pick` answers rays (or camera pixels), `verify` checks the GPU
//! path, the CPU path and the brute-force oracle against each other, `los` and `viewshed` test
//! lines of sight, `select` and `idbuffer` pick objects on screen, `render` draws the scene,
//! `probe` and `soak` check watertightness and endurance, `example` writes the built-in
//! example scene as files. Every command uses the built-in example scene when no `--scene` is
//! given. Errors print as one sentence and exit with code 2.

/// `std`'s `eprintln!`, but a line that cannot be written is lost instead of ending the process
/// with a panic: a closed standard error (`raypick … 2>&1 | head -1`) made every note, warning
/// and error sentence panic (exit 101). Defined before the modules, so they all use it.
macro_rules! eprintln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}

/// `std`'s `eprint!`, losing what cannot be written (see `eprintln!`).
macro_rules! eprint {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = write!(std::io::stderr(), $($arg)*);
    }};
}

mod cli;

/// Large buffers (files, scenes, trees, answers) on transparent huge pages, and freed large
/// blocks kept for the next: fewer page faults.
#[global_allocator]
static ALLOCATOR: raypick::huge_pages::Allocator = raypick::huge_pages::Allocator;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "raypick",
    version,
    about = "Exact, fast ray picking for 3D scenes on any GPU wgpu reaches, with a CPU path that gives the same answers"
)]
struct Cli {
    /// Show no progress (and no summary line) on standard error.
    #[arg(long, short, global = true)]
    quiet: bool,
    /// Memory budget for everything sized by arguments or file contents (image sizes, ray and
    /// probe counts, all-hits lists, sizes in file headers, the tree over a file's triangles):
    /// bytes, or a number with K, M, G or T (powers of 1024), e.g. 8G or 512M. A size over it
    /// is an error naming the value and the limit [default: half the machine's memory, or of
    /// `ulimit -v` or the control group's limit where less; under `ulimit -v`, at most half of
    /// what it leaves the process when a size is checked].
    #[arg(long, global = true, value_name = "SIZE", value_parser = raypick::budget::parse_limit)]
    max_memory: Option<u64>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// For each ray (or camera pixel): the nearest hit, any hit, or all hits (CSV or JSON).
    Pick(cli::pick::PickArgs),
    /// Run the GPU path, the CPU path and (for small scenes) brute force on the same rays and
    /// report mismatches per ray kind; exits 1 on any mismatch.
    Verify(cli::verify::VerifyArgs),
    /// Line of sight between pairs of points.
    Los(cli::los::LosArgs),
    /// Which targets (default: every terrain sample) an observer can see.
    Viewshed(cli::los::ViewshedArgs),
    /// The objects visible inside a screen rectangle of a camera view (default: the view
    /// `render` frames).
    Select(cli::select::SelectArgs),
    /// The object under every pixel of a camera view (default: the view `render` frames), as a
    /// colour PNG, a 16-bit id PNG or CSV.
    Idbuffer(cli::select::IdBufferArgs),
    /// Watertightness probes at shared edges and vertices, through both intersectors; exits 1
    /// if the watertight test leaks.
    Probe(cli::probe::ProbeArgs),
    /// Many batches through the GPU picker: a sample of each batch must match the CPU path, and
    /// resident memory may grow by at most --max-growth MiB after warm-up; exits 1 otherwise.
    Soak(cli::soak::SoakArgs),
    /// A ray-cast picture of the scene as a PNG, shaded by normal (hillshade), depth or object.
    Render(cli::render::RenderArgs),
    /// Build a scene's trees once and save the whole built scene as a .rpk file, which
    /// `--scene FILE.rpk` loads in every command with no rebuild.
    Build(cli::build::BuildArgs),
    /// Serve an HTTP JSON API (pick, scene, render) and a viewer page over one resident scene.
    Serve(cli::serve::ServeArgs),
    /// Write the built-in example scene as files (terrain.asc, tower.obj, hall.obj, and a scene
    /// description scene.json with layer masks), to load with --scene or --scenes.
    Example(cli::example::ExampleArgs),
    /// Build time, memory, throughput, end-to-end time and single-ray latency of every path
    /// (CPU at 1 and 2 threads, GPU, auto), and the CPU/GPU crossover batch size.
    Bench(cli::bench::BenchArgs),
}

fn main() -> ExitCode {
    let matches = match Cli::command().try_get_matches() {
        Ok(matches) => matches,
        Err(e) => {
            let args: Vec<_> = std::env::args_os().collect();
            if e.use_stderr()
                && let Some(sentence) =
                    cli::swallowed::option_taken_as_value(&Cli::command(), &args)
            {
                eprintln!("error: {sentence}");
                return ExitCode::from(2);
            }
            cli::exit_with_clap_error(e)
        }
    };
    let cli = match Cli::from_arg_matches(&matches) {
        Ok(cli) => cli,
        Err(e) => cli::exit_with_clap_error(e),
    };
    cli::progress::set_quiet(cli.quiet);
    // A write past the file-size limit (`ulimit -f`) fails with an error that names the file
    // (EFBIG) instead of the signal killing the process without a word.
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to "ignore" installs no handler.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
    cli::mapped_file_guard::install();
    if let Some(bytes) = cli.max_memory {
        raypick::budget::set_limit(bytes);
    }
    if let Err(sentence) = cli::threads::start() {
        eprintln!("error: {sentence}");
        return ExitCode::from(2);
    }
    let (_, sub) = matches.subcommand().expect("a subcommand is required");
    // An --out that is also an input is refused before anything is read or written.
    let result = cli::out_guard::refuse_inputs(sub).and_then(|()| match cli.command {
        Command::Pick(args) => cli::pick::run(args, sub),
        Command::Verify(args) => cli::verify::run(args, sub),
        Command::Los(args) => cli::los::run_los(args, sub),
        Command::Viewshed(args) => cli::los::run_viewshed(args, sub),
        Command::Select(args) => cli::select::run_select(args, sub),
        Command::Idbuffer(args) => cli::select::run_idbuffer(args, sub),
        Command::Probe(args) => cli::probe::run(args, sub),
        Command::Soak(args) => cli::soak::run(args, sub),
        Command::Render(args) => cli::render::run(args, sub),
        Command::Serve(args) => cli::serve::run(args, sub),
        Command::Example(args) => cli::example::run(args),
        Command::Bench(args) => cli::bench::run(args, sub),
        Command::Build(args) => cli::build::run(args, sub),
    });
    match result {
        Ok(code) => code,
        Err(e) => {
            // A long message (one that repeats a huge bad token: a JSON, glTF or GeoTIFF
            // reader's) is cut to short tokens; ordinary ones, with their paths, stay whole.
            // Line breaks stay only in a driver's own text; elsewhere one in a file name or
            // token is written as `\n`, so the message stays one line.
            let driver_text = matches!(
                e,
                raypick::Error::Gpu(_)
                    | raypick::Error::DeviceLost(_)
                    | raypick::Error::RequestDevice(_)
                    | raypick::Error::NoAdapter(_)
            );
            let message = raypick::error::escape_controls(&e.to_string(), driver_text).into_owned();
            if message.len() > 1000 {
                eprintln!("error: {}", raypick::error::shorten_tokens(&message, 2000));
            } else {
                eprintln!("error: {message}");
            }
            ExitCode::from(2)
        }
    }
}
