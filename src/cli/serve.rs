//! `raypick serve`: builds the scene once, keeps it resident in one picker, and answers HTTP
//! requests (JSON picks, scene facts, rendered views, the viewer page) until interrupted.

use super::scene_args::SceneArgs;
use clap::{ArgMatches, Args};
use raypick::server::{Server, ServerConfig};
use raypick::{Backend, Error};
use std::io::Write;
use std::net::SocketAddr;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

#[derive(Args, Debug)]
pub struct ServeArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Address to listen on. Loopback by default; port 0 picks a free port (the address is
    /// printed). Anyone who can reach a non-loopback address can use the server.
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub addr: SocketAddr,
    /// Which path answers picks.
    #[arg(long, value_parser = crate::cli::choice::choice::<Backend>(), default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Most rays (or pixels) per request.
    #[arg(long, default_value_t = ServerConfig::default().max_rays)]
    pub max_rays: usize,
    /// Largest request body, in bytes.
    #[arg(long, default_value_t = ServerConfig::default().max_body_bytes)]
    pub max_body_bytes: usize,
    /// Most connections served at once; further ones wait until one closes.
    #[arg(long, default_value_t = ServerConfig::default().max_connections)]
    pub max_connections: usize,
    /// Seconds a connection with no request in progress (idle, sending its headers, or not
    /// reading its answer) stays open.
    #[arg(long, default_value_t = ServerConfig::default().idle_timeout.as_secs_f64())]
    pub idle_timeout: f64,
    /// Seconds a request body has to arrive whole (408 after).
    #[arg(long, default_value_t = ServerConfig::default().body_timeout.as_secs_f64())]
    pub body_timeout: f64,
    /// Memory budget of all requests in progress together (e.g. 2G, 512M), at most
    /// --max-memory; requests beyond it wait briefly, then get 503. Default: a quarter of
    /// --max-memory, at least 64 MiB (or all of a smaller --max-memory).
    #[arg(long, value_parser = raypick::budget::parse_size)]
    pub memory_budget: Option<u64>,
    /// Most triangles `POST /objects` may add over the server's life, copies included, each
    /// object counting as at least 64 (an instance of a stored mesh, or a removed object
    /// once an addition has given its triangles back, as 64); 413 past it.
    #[arg(long, default_value_t = ServerConfig::default().max_added_triangles)]
    pub max_added_triangles: usize,
    /// A host name the server answers to besides IP addresses and localhost (repeatable; `*`
    /// for any): a name of this machine, or a reverse proxy's public name. Requests naming
    /// another `Host` get 403, so that no web page can reach the server through a name of its
    /// own (DNS rebinding).
    #[arg(long = "allow-host", value_name = "NAME")]
    pub allow_hosts: Vec<String>,
    /// Seconds of the worker's time one pick or render request may take; past it the work
    /// stops and the request gets 413 (the count of rays answered, and to send fewer).
    #[arg(long, default_value_t = ServerConfig::default().max_work.as_secs_f64())]
    pub max_work_seconds: f64,
}

/// `seconds` as a timeout: a positive, finite number of seconds.
fn timeout(flag: &str, seconds: f64) -> Result<Duration, Error> {
    // At least a millisecond: shorter ones (1e-10, which a Duration rounds to nothing) dropped
    // every connection unanswered.
    if seconds.is_finite() && (1e-3..=1e9).contains(&seconds) {
        Ok(Duration::from_secs_f64(seconds))
    } else {
        Err(Error::Invalid(format!(
            "{flag} {} is not a timeout; give a number of seconds from 0.001 to 1e9",
            raypick::io::output::csv_number(seconds)
        )))
    }
}

/// The requests' memory budget: `--memory-budget`, which must fit within the process's
/// (`--max-memory`), or the default.
fn memory_budget(asked: Option<u64>) -> Result<u64, Error> {
    let process = raypick::budget::limit();
    match asked {
        None => Ok(ServerConfig::default_memory_budget()),
        Some(bytes) if bytes <= process => Ok(bytes),
        Some(bytes) => Err(Error::Invalid(format!(
            "--memory-budget {} is more than the process's memory budget of {} (--max-memory; by \
             default half of what the process can have); give a smaller --memory-budget or a larger \
             --max-memory",
            raypick::budget::human(bytes),
            raypick::budget::human(process)
        ))),
    }
}

pub fn run(args: ServeArgs, matches: &ArgMatches) -> Result<ExitCode, Error> {
    // A server gives its memory back after a burst of large requests.
    raypick::huge_pages::keep_freed_blocks(false);
    // A limit of 0 would refuse every request (or serve no connection): refused, not raised
    // to 1 without a word.
    for (flag, value) in [
        ("--max-rays", args.max_rays),
        ("--max-body-bytes", args.max_body_bytes),
        ("--max-connections", args.max_connections),
    ] {
        if value == 0 {
            return Err(Error::Invalid(format!(
                "{flag} 0 would refuse every request; give at least 1"
            )));
        }
    }
    let allowed_hosts = args
        .allow_hosts
        .iter()
        .map(|name| {
            raypick::server::host::check_allowed_host(name)
                .map_err(|why| Error::Invalid(format!("--allow-host {why}")))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let no_names_allowed = allowed_hosts.is_empty();
    let config = ServerConfig {
        max_rays: args.max_rays,
        max_body_bytes: args.max_body_bytes,
        max_connections: args.max_connections,
        idle_timeout: timeout("--idle-timeout", args.idle_timeout)?,
        body_timeout: timeout("--body-timeout", args.body_timeout)?,
        memory_budget: memory_budget(args.memory_budget)?,
        max_added_triangles: args.max_added_triangles,
        allowed_hosts,
        max_work: timeout("--max-work-seconds", args.max_work_seconds)?,
        ..ServerConfig::default()
    };
    let built = Arc::new(args.scene.build_instanced(matches, true)?.0);
    let triangles = match super::scene_args::instances_of(&built) {
        Some(instances) => format!("{} triangles ({instances})", built.world_triangle_count()),
        None => format!("{} triangles", built.world_triangle_count()),
    };
    let server = Server::new(built, args.backend, config)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|source| Error::Io {
            path: "the async runtime".into(),
            source,
        })?;
    runtime.block_on(async {
        let listener = tokio::net::TcpListener::bind(args.addr)
            .await
            .map_err(|source| Error::Io {
                path: args.addr.to_string(),
                source,
            })?;
        let bound = listener.local_addr().map_err(|source| Error::Io {
            path: args.addr.to_string(),
            source,
        })?;
        if !bound.ip().is_loopback() {
            eprintln!(
                "warning: listening on {bound}, which is not a loopback address: anyone who can \
                 reach it can use this server"
            );
            if no_names_allowed {
                eprintln!(
                    "note: requests that reach it by a host name get 403 unless the name is \
                     given with --allow-host NAME (IP addresses and localhost are answered)"
                );
            }
        }
        say!(
            "raypick serve: {triangles} on {}; listening on http://{bound}/",
            server.device()
        )?;
        let _ = std::io::stdout().flush();
        server.serve(listener).await
    })?;
    Ok(ExitCode::SUCCESS)
}
