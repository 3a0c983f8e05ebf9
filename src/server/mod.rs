//! `raypick serve`: an HTTP JSON API (axum on tokio) over one scene kept resident in a picker,
//! and the viewer page it serves.
//!
//! This module owns the [`Server`] (its configuration, start-up and serving); the routes and
//! their JSON live in `api`, the picking worker and its batching in [`batcher`], the page in
//! [`page`], the refusal of other sites' requests in `origin`, picks answered in steps (and
//! dropped when their client is gone) in `steps`, the `connection: close` of an answer to a
//! request whose body was left unread in `unread_body`. It speaks HTTP/1.1 (and 1.0): a client
//! opening with HTTP/2's preface (in one piece or several) is answered GOAWAY with
//! HTTP_1_1_REQUIRED (`http2_refusal`).
//!
//! # Threads
//!
//! The scene is built once. ONE worker thread owns the picker ([`crate::GpuPicker`],
//! [`crate::CpuPicker`] or [`crate::auto::AutoPicker`]); HTTP handlers send it jobs over a
//! channel. Pick requests that arrive together — queued while the worker was busy, or within
//! [`ServerConfig::batch_window`] (default 1 ms) after the first — are answered by ONE
//! [`crate::Picker::query`] call per distinct (mode, cull, max_hits, intersector), and the
//! answers are split back to each request. `GET /stats` counts requests and query calls.
//!
//! # Routes
//!
//! Errors are JSON `{"error": "sentence"}` with a 4xx status for the client's mistakes (400 for
//! malformed JSON, unknown fields, a bad camera or option, naming the field's path; 413 for a body over
//! [`ServerConfig::max_body_bytes`], more than [`ServerConfig::max_rays`] rays, or in mode `all`
//! more than [`ServerConfig::max_hit_entries`] rays x `max_hits`; 404; 405; 408 for a body not
//! sent whole within [`ServerConfig::body_timeout`]; 403 for a `POST`, `PATCH` or `DELETE` from
//! another web site, by its `Origin` header: `origin`, and for any request through a host name
//! the server was not given, against DNS rebinding: [`host`]; 413 for a pick or render whose
//! steps pass [`ServerConfig::max_work`]), 503 when the request's memory does not
//! fit the server's memory budget (see below) or its work the process's
//! ([`crate::Error::OverBudget`]), and 500 when picking itself fails. A sentence
//! quotes at most 60 characters of any token of the request (a field name, a value), then "…".
//!
//! # Limits on slow clients and memory
//!
//! - At most [`ServerConfig::max_connections`] connections (default 1024) are served at once;
//!   further ones wait in the listener's backlog until one closes.
//! - A connection with no request being handled — idle between requests, sending its headers,
//!   or not reading its answer — is closed [`ServerConfig::idle_timeout`] (default 20 s) after
//!   it last became idle or took answer bytes, however slowly it trickles bytes in.
//! - A request body must arrive whole within [`ServerConfig::body_timeout`] (default 30 s).
//! - Each request's memory — its body, its rays (`Query::bytes_per_ray`), its all-hits lists
//!   and its JSON answer, or a render's pixels — is reserved from
//!   [`ServerConfig::memory_budget`] (default a quarter of [`crate::budget::limit`]): a body's
//!   as its bytes arrive, the rest before the work starts, given back when the answer has been
//!   sent (a pick's JSON, a render's PNG) or the work is done. A request that cannot fit at all is
//!   answered 503 at once; one that must wait for others to finish waits up to
//!   [`ServerConfig::memory_wait`] (default 5 s), then gets 503. After large requests the
//!   allocator is asked to give freed memory back to the system.
//! - A pick whose client is gone (its connection closed, its handler dropped) is not answered:
//!   the worker skips it, or stops it between two of its steps (`steps`).
//!
//! ## `POST /pick`
//!
//! The body is either explicit rays:
//!
//! ```json
//! {"rays": [{"origin": [x, y, z], "dir": [x, y, z], "tmin": 0, "tmax": 1e30,
//!            "mask": 4294967295}, ...],
//!  "mode": "closest", "cull": "none", "max_hits": 16}
//! ```
//!
//! or camera pixels:
//!
//! ```json
//! {"camera": {"perspective": {...}}, "pixels": [[x, y], ...], "mode": "closest"}
//! ```
//!
//! `camera` is a camera file's JSON ([`crate::apps::camera`]). Pixel coordinates are pixel
//! *indices*, as in pixel files ([`crate::io::pixel_file::parse_pixel_indices_as_centers`]): `x` is the
//! column from the left, `y` the row from the top, integers name whole pixels and are picked
//! through their centres (`[3, 4]` is the ray through `(3.5, 4.5)`), fractional values are
//! offsets from that centre. Options, all optional: `mode` (`closest`, `any`, `all`), `cull`
//! (`none`, `back`, `front`), `max_hits` (mode `all`, 1 ..= 1024, default 16), `intersector`
//! (`watertight` or `moller-trumbore`; default [`crate::Intersector::default`]), and `tmin`,
//! `tmax`, `mask` as defaults for rays without their own (and for pixel rays); `tmax` absent
//! or `null` is unbounded. `mask` may also be spelled `ray_mask`, as the command line's
//! `--ray-mask` (in a request and in a ray; one of the two, not both). Numbers are read correctly rounded (serde_json's
//! `float_roundtrip`), so rays and cameras arrive bit for bit as the client wrote them.
//!
//! The answer has one result per ray, in order:
//!
//! ```json
//! {"results": [{"hit": true, "t": 12.5, "object": 1, "object_name": "tower",
//!               "triangle": 7, "u": 0.25, "v": 0.5, "position": [x, y, z],
//!               "normal": [x, y, z], "row": 3, "col": 4},
//!              {"hit": false}, {"hit": false, "invalid": true}]}
//! ```
//!
//! `row`/`col` appear for terrain-grid hits only; `invalid` marks rays that cannot be traced
//! (zero direction, `tmin > tmax`). Numbers are written in shortest round-trip form, so every
//! f64 digit survives. In mode `all` each result is `{"hits": [hit, ...], "overflow": bool}`
//! (hits sorted by `t`; `overflow` when more than `max_hits` were found).
//!
//! ## `GET /scene`
//!
//! The backend and device, the bounds, the objects (id, name, triangles, mask, grid shape,
//! and the transform last set by an edit, `null` for as loaded; removed objects are left out),
//! the triangle count, the tree (nodes, leaves, depth, GPU bytes and bytes per triangle), the
//! framing camera the viewer starts from, the limits and the counters.
//!
//! ## `GET /render?camera=<url-encoded camera JSON>&shade=normal`
//!
//! A PNG of the view ([`crate::apps::render`]); `shade` is `normal`, `depth` or `object`. Without
//! `camera`, the framing camera ([`crate::apps::camera::Camera::frame_bounds`]) at `width` x `height`
//! (default [`ServerConfig::view_width`] x [`ServerConfig::view_height`]).
//!
//! ## `POST /objects`, `PATCH /objects/{id}`, `DELETE /objects/{id}`
//!
//! Scene edits, answered `{"object": id}`, with `"warnings"` (a list of sentences) where the
//! edit placed the object where it is picked less exactly
//! ([`crate::frame::faults::placement_warnings`]). `POST` adds `{"mesh": id}` (a copy of that object's
//! mesh as it was loaded or added) or `{"vertices": [[x, y, z], ...], "triangles": [[i, j, k],
//! ...]}`, either with an optional `"transform"` (3 × 4 row-major, file → world) and `"mask"`;
//! the tree is built again. `PATCH` sets `"transform"` (relative to the object as loaded or
//! added: a refit, or a rebuild when a mirror comes or goes) and/or `"mask"`. `DELETE` removes
//! the object (its mask becomes 0: it is never hit again). The worker applies edits between
//! query calls in arrival order, so no pick mixes two versions of the scene. 400 for a bad body
//! (a singular transform, an index out of range, neither or both kinds of mesh), 404 for an
//! unknown or removed id, 413 past [`ServerConfig::max_added_triangles`].
//!
//! ## `GET /stats`
//!
//! The worker's [`Stats`].
//!
//! ## `GET /`
//!
//! The viewer: the rendered view; click picks the pixel and shows the world position, object,
//! triangle and terrain cell, and selects the object; drag orbits around the target; the wheel
//! zooms; shift-drag moves the selected object over the terrain (`PATCH /objects/{id}`).

mod api;
mod bare_errors;
pub mod batcher;
mod frame_faults;
mod held_body;
pub mod host;
mod object_only;
mod origin;
pub mod page;
mod steps;
mod unread_body;

pub use batcher::Stats;

use crate::error::{Error, Result};
use crate::picker::{Backend, BuiltScene};
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

/// The server's limits and defaults.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ServerConfig {
    /// The largest request body accepted, in bytes (larger ones get 413).
    pub max_body_bytes: usize,
    /// The most rays one request may ask for (pick rays or pixels, and render pixels).
    pub max_rays: usize,
    /// How long the worker waits after a request for others to batch with it.
    pub batch_window: Duration,
    /// Width of the framing view (the viewer's first view and `/render` without a camera).
    pub view_width: u32,
    /// Height of the framing view.
    pub view_height: u32,
    /// The idle and header timeout: a connection with no request being handled — idle between
    /// requests, still sending a request's headers (however slowly), or not reading its answer
    /// — is closed once this long has passed since it last became idle or last took answer
    /// bytes.
    pub idle_timeout: Duration,
    /// The body timeout: a request body must arrive whole within this long after its headers,
    /// or the request is answered 408 and the connection closed.
    pub body_timeout: Duration,
    /// The most connections served at once; further connections wait in the listener's
    /// backlog until one closes.
    pub max_connections: usize,
    /// The memory budget of all requests in progress together, in bytes: each request's
    /// estimated memory (its body, rays, hit lists and answer, or its image) is reserved from
    /// it before the work starts. Part of the process's budget ([`crate::budget::limit`]):
    /// `raypick serve` refuses a larger one, and [`Server::new`] lowers it to the process's
    /// budget as that is once the worker is ready (under `ulimit -v` the scene's and a GPU
    /// driver's mappings count against it).
    pub memory_budget: u64,
    /// How long a request waits for its memory to become free in the budget before it is
    /// answered 503.
    pub memory_wait: Duration,
    /// The most triangles `POST /objects` may add over the server's life (copies included,
    /// each object counting as at least 64: its own entries weigh about that much; an
    /// instance of a stored mesh, and an object removed once the next addition has given its
    /// triangles back, as 64): an object that would pass it is refused with 413, so clients
    /// cannot grow the scene without bound.
    pub max_added_triangles: usize,
    /// Host names the server answers to besides IP addresses, `localhost` and names under
    /// `.localhost` (lower case; [`host::ANY_HOST`] for any): requests with another `Host` get
    /// 403, against pages that point their own names at the server ([`host`]).
    pub allowed_hosts: Vec<String>,
    /// The longest the worker spends on one pick or render request (each request of a batch
    /// asked together on its own clock, from when its own work starts): past it the work stops
    /// between two steps and the request gets 413 with the count answered, so one costly
    /// request cannot hold every other client's picks for hours.
    pub max_work: Duration,
}

impl ServerConfig {
    /// The most all-hits list entries (`rays x max_hits`) one request may ask for in mode
    /// `all`: 16 per ray of [`ServerConfig::max_rays`], so that a request's hit lists stay
    /// within a bounded amount of memory.
    pub fn max_hit_entries(&self) -> usize {
        self.max_rays.saturating_mul(16)
    }

    /// The default [`ServerConfig::memory_budget`]: a quarter of the process's memory budget
    /// ([`crate::budget::limit`]), at least 64 MiB, but never more than the process's budget.
    pub fn default_memory_budget() -> u64 {
        let process = crate::budget::limit();
        (process / 4).max(64 << 20).min(process)
    }
}

impl Default for ServerConfig {
    fn default() -> Self {
        Self {
            max_body_bytes: 8 << 20,
            max_rays: 1 << 20,
            batch_window: Duration::from_millis(1),
            view_width: 640,
            view_height: 480,
            idle_timeout: Duration::from_secs(20),
            body_timeout: Duration::from_secs(30),
            max_connections: 1024,
            memory_budget: Self::default_memory_budget(),
            memory_wait: Duration::from_secs(5),
            max_added_triangles: 1 << 23,
            allowed_hosts: Vec::new(),
            max_work: Duration::from_secs(60),
        }
    }
}

/// A started picking worker with its routes, ready to serve on a listener.
pub struct Server {
    state: Arc<api::AppState>,
}

impl Server {
    /// Starts the picking worker for `backend` over `built` and waits until its picker is ready
    /// (for the GPU: the device is opened and the scene uploaded). Blocks; call it before
    /// entering the async runtime, or from `spawn_blocking`. Fails as building the picker
    /// fails (no GPU adapter, a scene too large for the GPU), and on limits that would refuse
    /// every request or pass the process's memory budget as set ([`crate::budget`]); under an
    /// address-space limit the requests' budget is lowered to the process's budget once the
    /// worker is ready.
    pub fn new(
        built: Arc<BuiltScene>,
        backend: Backend,
        mut config: ServerConfig,
    ) -> Result<Server> {
        if config.max_rays == 0 || config.max_body_bytes == 0 || config.max_connections == 0 {
            return Err(crate::Error::Invalid(format!(
                "the server's limits must be at least 1 (max_rays {}, max_body_bytes {}, \
                 max_connections {})",
                config.max_rays, config.max_body_bytes, config.max_connections
            )));
        }
        // A budget over the process's as set (or by default) is the caller's mistake; the
        // address-space limit's share of it is taken below, once the worker is ready.
        let process = crate::budget::set_or_default();
        if config.memory_budget > process {
            return Err(crate::Error::Invalid(format!(
                "the requests' memory budget, {}, is more than the process's, {}",
                crate::budget::human(config.memory_budget),
                crate::budget::human(process)
            )));
        }
        let view: batcher::SharedView = Arc::new(std::sync::Mutex::new(Arc::new(
            batcher::SceneView::of(&built, Vec::new()),
        )));
        let worker = batcher::Worker::start(
            built,
            backend,
            config.batch_window,
            (
                config.max_rays.saturating_mul(4),
                config.max_hit_entries().saturating_mul(4),
            ),
            view.clone(),
            config.max_added_triangles,
            config.max_work,
        )?;
        // The requests' budget is at most the process's as it is once the worker is ready:
        // under an address-space limit, half of what the limit leaves, which the scene and a
        // GPU driver's mappings (hundreds of MiB) have taken from, so a request within it
        // cannot abort the process (the default, a quarter of the budget and at least 64 MiB,
        // would refuse to start under `ulimit -v 300000`).
        config.memory_budget = config.memory_budget.min(crate::budget::limit());
        Ok(Server {
            state: Arc::new(api::AppState {
                worker,
                view,
                backend,
                memory: api::MemoryBudget::new(config.memory_budget, config.memory_wait),
                config,
            }),
        })
    }

    /// What answers picks ([`crate::Picker::describe`]), e.g.
    /// `gpu llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan, Cpu)` or `cpu engine (avx2, 2 threads)`.
    pub fn device(&self) -> &str {
        self.state.worker.description()
    }

    /// A snapshot of the worker's counters.
    pub fn stats(&self) -> Stats {
        self.state.worker.stats()
    }

    /// The routes, for embedding in another axum application or calling without a socket.
    pub fn router(&self) -> axum::Router {
        api::router(self.state.clone())
    }

    /// Serves on `listener` until the listener fails; the worker stops when the server is
    /// dropped. At most [`ServerConfig::max_connections`] connections are served at once;
    /// connections without a request in progress are closed after
    /// [`ServerConfig::idle_timeout`].
    pub async fn serve(self, listener: tokio::net::TcpListener) -> Result<()> {
        let address = listener
            .local_addr()
            .map_or_else(|_| "the listener".to_owned(), |a| a.to_string());
        let config = &self.state.config;
        let limited = LimitedListener {
            inner: listener,
            slots: Arc::new(Semaphore::new(
                config.max_connections.clamp(1, Semaphore::MAX_PERMITS),
            )),
            idle_timeout: config.idle_timeout,
        };
        let app = self
            .router()
            .layer(axum::middleware::from_fn(track_in_flight));
        axum::serve(
            limited,
            app.into_make_service_with_connect_info::<Connection>(),
        )
        .await
        .map_err(|source| Error::Io {
            path: address,
            source,
        })
    }
}

/// What one connection's IO and its requests share: how many requests are being handled, and
/// when the connection last made progress (became idle, or took answer bytes).
#[derive(Debug)]
struct ConnectionState {
    in_flight: AtomicUsize,
    last_progress: Mutex<Instant>,
}

impl ConnectionState {
    fn touch(&self) {
        if let Ok(mut last) = self.last_progress.lock() {
            *last = Instant::now();
        }
    }
}

/// A connection's shared state, as the connect info of its requests.
#[derive(Clone, Debug)]
struct Connection(Arc<ConnectionState>);

impl axum::extract::connect_info::Connected<axum::serve::IncomingStream<'_, LimitedListener>>
    for Connection
{
    fn connect_info(stream: axum::serve::IncomingStream<'_, LimitedListener>) -> Self {
        Connection(stream.io().state.clone())
    }
}

/// Counts the request as in progress on its connection while its handler runs.
async fn track_in_flight(
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    let connection = request
        .extensions()
        .get::<axum::extract::ConnectInfo<Connection>>()
        .map(|info| info.0.0.clone());
    let _guard = connection.map(|state| {
        state.in_flight.fetch_add(1, Ordering::SeqCst);
        InFlight(state)
    });
    next.run(request).await
}

/// A request in progress; when it ends, the connection's idle time starts.
struct InFlight(Arc<ConnectionState>);

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0.touch();
        self.0.in_flight.fetch_sub(1, Ordering::SeqCst);
    }
}

/// A TCP listener that serves at most so many connections at once and wraps each in
/// [`LimitedIo`].
struct LimitedListener {
    inner: tokio::net::TcpListener,
    slots: Arc<Semaphore>,
    idle_timeout: Duration,
}

impl axum::serve::Listener for LimitedListener {
    type Io = LimitedIo;
    type Addr = std::net::SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        // Wait for a free slot before accepting: further connections wait in the backlog.
        let slot = loop {
            if let Ok(slot) = self.slots.clone().acquire_owned().await {
                break slot;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        };
        let (stream, addr) = axum::serve::Listener::accept(&mut self.inner).await;
        let _ = stream.set_nodelay(true);
        let io = LimitedIo {
            inner: stream,
            state: Arc::new(ConnectionState {
                in_flight: AtomicUsize::new(0),
                last_progress: Mutex::new(Instant::now()),
            }),
            idle_timeout: self.idle_timeout,
            sleep: Box::pin(tokio::time::sleep(self.idle_timeout)),
            answer: Vec::new(),
            answer_sent: 0,
            unacknowledged: None,
            opening: Opening::Unsure(Vec::new()),
            _slot: slot,
        };
        (io, addr)
    }

    fn local_addr(&self) -> std::io::Result<Self::Addr> {
        self.inner.local_addr()
    }
}

/// A connection that fails its reads and writes (so the server closes it) once it has had no
/// request in progress for [`ServerConfig::idle_timeout`] since it last made progress, frees
/// its connection slot when dropped, and gives hyper's empty automatic error answers their
/// sentence ([`bare_errors`]).
struct LimitedIo {
    inner: tokio::net::TcpStream,
    state: Arc<ConnectionState>,
    idle_timeout: Duration,
    sleep: Pin<Box<tokio::time::Sleep>>,
    /// An automatic error answer with its sentence, taken whole from hyper and written from
    /// here (before anything else, and by each flush and shutdown); `answer_sent` bytes of it
    /// are out.
    answer: Vec<u8>,
    answer_sent: usize,
    /// The bytes the socket held unacknowledged when a write last began to wait (or at the
    /// last look since): [`LimitedIo::still_reading`].
    unacknowledged: Option<usize>,
    /// What the connection opened with: HTTP/2's preface or not.
    opening: Opening,
    _slot: OwnedSemaphorePermit,
}

/// What a connection opened with, read before hyper sees a byte ([`LimitedIo::poll_opening`]).
enum Opening {
    /// The bytes read so far could still be HTTP/2's preface, however the client's writes
    /// split it.
    Unsure(Vec<u8>),
    /// Not the preface: HTTP/1, whose bytes read while unsure hyper has not been given yet
    /// (empty once it has).
    Http1(Vec<u8>),
    /// HTTP/2's preface: the client is answered [`http2_refusal`], and what it sends is read and
    /// dropped until it closes (hyper sees no request).
    Http2,
}

/// What an HTTP/2 client that starts with the connection preface (`curl --http2-prior-knowledge`)
/// is answered, in its own protocol: the server's preface (an empty SETTINGS frame), then
/// GOAWAY with HTTP_1_1_REQUIRED (0xd) and a sentence. hyper, serving HTTP/1 only, reset such
/// a connection without a word.
fn http2_refusal() -> Vec<u8> {
    const WHY: &[u8] = b"raypick serves HTTP/1.1 only";
    // SETTINGS: length 0, type 4, no flags, stream 0.
    let mut frames = vec![0, 0, 0, 4, 0, 0, 0, 0, 0];
    // GOAWAY: length, type 7, no flags, stream 0; last stream 0, error code, the sentence.
    let length = (8 + WHY.len()) as u32;
    frames.extend_from_slice(&length.to_be_bytes()[1..]);
    frames.extend_from_slice(&[7, 0, 0, 0, 0, 0]);
    frames.extend_from_slice(&0u32.to_be_bytes());
    frames.extend_from_slice(&0xdu32.to_be_bytes());
    frames.extend_from_slice(WHY);
    frames
}

/// The start of HTTP/2's connection preface.
const HTTP2_PREFACE: &[u8] = b"PRI * HTTP/2.0\r\n";

/// The least pace, in bytes a second, at which a client taking an answer keeps its connection
/// past the idle timeout ([`LimitedIo::still_reading`]).
const MIN_READ_RATE: f64 = 16.0 * 1024.0;

/// The bytes `stream` holds that the client has not acknowledged yet (Linux's `SIOCOUTQ`);
/// `None` where that cannot be asked.
#[cfg(target_os = "linux")]
fn unacknowledged(stream: &tokio::net::TcpStream) -> Option<usize> {
    use std::os::fd::AsRawFd;
    let mut queued: libc::c_int = 0;
    // SAFETY: `TIOCOUTQ` (`SIOCOUTQ` on a TCP socket) writes one int through the pointer,
    // which points to one; the descriptor is the stream's, open while it is borrowed.
    let done = unsafe { libc::ioctl(stream.as_raw_fd(), libc::TIOCOUTQ, &mut queued) };
    (done == 0).then(|| queued.max(0) as usize)
}

/// Not asked elsewhere: a slow reader's answer ends at the idle timeout there.
#[cfg(not(target_os = "linux"))]
fn unacknowledged(_: &tokio::net::TcpStream) -> Option<usize> {
    None
}

impl LimitedIo {
    /// When the connection times out, if no request is in progress.
    fn deadline(&self) -> Option<Instant> {
        if self.state.in_flight.load(Ordering::SeqCst) > 0 {
            return None;
        }
        let last = self
            .state
            .last_progress
            .lock()
            .map_or_else(|_| Instant::now(), |l| *l);
        Some(last + self.idle_timeout)
    }

    fn timed_out(&self) -> std::io::Error {
        std::io::Error::new(
            std::io::ErrorKind::TimedOut,
            format!(
                "the connection had no request in progress for {:?}",
                self.idle_timeout
            ),
        )
    }

    /// Whether the deadline has passed (and the client has not taken answer bytes meanwhile:
    /// [`LimitedIo::still_reading`]).
    fn expired(&mut self) -> bool {
        self.deadline().is_some_and(|d| Instant::now() >= d) && !self.still_reading()
    }

    /// Whether a client is taking an answer that waits on it, only slower than the socket
    /// wakes its writer (which waits for a third of a send buffer of up to several MiB to
    /// drain: a client reading 30–100 KB/s had a 26 MB answer cut short at the idle timeout).
    /// Yes when the bytes the socket holds that the client has not acknowledged went down, by
    /// [`MIN_READ_RATE`] over the idle timeout at least, since the write began to wait or since
    /// the last look; that counts as progress.
    fn still_reading(&mut self) -> bool {
        let (Some(was), Some(now)) = (self.unacknowledged, unacknowledged(&self.inner)) else {
            return false;
        };
        // At least `MIN_READ_RATE` over the idle timeout: a client taking a segment now and
        // then does not hold its connection (and the answer's memory) for ever.
        let least = (self.idle_timeout.as_secs_f64() * MIN_READ_RATE) as usize;
        if now.saturating_add(least.max(1)) > was {
            return false;
        }
        self.unacknowledged = Some(now);
        self.state.touch();
        true
    }

    /// After a pending read or write: wakes the task at the deadline, and fails once it passed
    /// (unless the client is still taking the answer).
    fn poll_deadline<T>(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<T>> {
        loop {
            let Some(deadline) = self.deadline() else {
                return Poll::Pending;
            };
            self.sleep
                .as_mut()
                .reset(tokio::time::Instant::from_std(deadline));
            match self.sleep.as_mut().poll(cx) {
                Poll::Ready(()) if self.still_reading() => {}
                Poll::Ready(()) => return Poll::Ready(Err(self.timed_out())),
                Poll::Pending => return Poll::Pending,
            }
        }
    }

    /// Writes what is left of [`LimitedIo::answer`]; ready once it is all out.
    fn poll_answer(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        while self.answer_sent < self.answer.len() {
            let written =
                Pin::new(&mut self.inner).poll_write(cx, &self.answer[self.answer_sent..]);
            match self.after_write(cx, written) {
                Poll::Ready(Ok(0)) => {
                    return Poll::Ready(Err(std::io::ErrorKind::WriteZero.into()));
                }
                Poll::Ready(Ok(n)) => self.answer_sent += n,
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                Poll::Pending => return Poll::Pending,
            }
        }
        Poll::Ready(Ok(()))
    }

    /// Takes `buf` whole when it is one of hyper's empty automatic error answers, to be sent
    /// with its sentence instead ([`bare_errors::with_sentence`]): its length, as written.
    fn took_bare_error(&mut self, cx: &mut Context<'_>, buf: &[u8]) -> Option<usize> {
        let answer = bare_errors::with_sentence(buf)?;
        (self.answer, self.answer_sent) = (answer, 0);
        // Sent now as far as the socket takes it; the flush that follows sends the rest (or
        // returns the error).
        let _ = self.poll_answer(cx);
        Some(buf.len())
    }

    /// A write's outcome: pending waits on the deadline; written bytes count as activity.
    fn after_write(
        &mut self,
        cx: &mut Context<'_>,
        written: Poll<std::io::Result<usize>>,
    ) -> Poll<std::io::Result<usize>> {
        match written {
            Poll::Pending => {
                // Where the client stands as the write begins to wait.
                self.unacknowledged = unacknowledged(&self.inner);
                self.poll_deadline(cx)
            }
            Poll::Ready(Ok(n)) => {
                if n > 0 {
                    self.state.touch();
                    self.unacknowledged = None;
                }
                Poll::Ready(Ok(n))
            }
            ready => ready,
        }
    }
}

impl AsyncRead for LimitedIo {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        // Headers sent byte by byte still end at the deadline.
        if this.expired() {
            return Poll::Ready(Err(this.timed_out()));
        }
        std::task::ready!(this.poll_opening(cx))?;
        match &mut this.opening {
            Opening::Http2 => return this.poll_refuse_http2(cx),
            Opening::Http1(held) if !held.is_empty() => {
                let n = held.len().min(buf.remaining());
                buf.put_slice(&held[..n]);
                held.drain(..n);
                return Poll::Ready(Ok(()));
            }
            _ => {}
        }
        match Pin::new(&mut this.inner).poll_read(cx, buf) {
            Poll::Pending => this.poll_deadline(cx),
            ready => ready,
        }
    }
}

impl LimitedIo {
    /// Reads the connection's first bytes, no more than HTTP/2's preface holds, until they are
    /// the preface ([`Opening::Http2`]) or cannot be (held for hyper: [`Opening::Http1`]), or
    /// the client closes first; ready at once when that is known. A preface sent a few bytes
    /// at a time was given to hyper, which reset the connection without a word.
    fn poll_opening(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        while let Opening::Unsure(seen) = &mut self.opening {
            let mut bytes = [0u8; HTTP2_PREFACE.len()];
            let mut read = ReadBuf::new(&mut bytes[..HTTP2_PREFACE.len() - seen.len()]);
            match Pin::new(&mut self.inner).poll_read(cx, &mut read) {
                Poll::Pending => return self.poll_deadline(cx),
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                Poll::Ready(Ok(())) => {
                    let closed = read.filled().is_empty();
                    seen.extend_from_slice(read.filled());
                    if seen == HTTP2_PREFACE {
                        self.opening = Opening::Http2;
                        (self.answer, self.answer_sent) = (http2_refusal(), 0);
                    } else if closed || !HTTP2_PREFACE.starts_with(seen) {
                        self.opening = Opening::Http1(std::mem::take(seen));
                    }
                }
            }
        }
        Poll::Ready(Ok(()))
    }

    /// Sends an HTTP/2 client [`http2_refusal`], then reads and drops what it sends until it
    /// closes, and ends the connection for hyper (closed with the client's bytes unread, the
    /// connection would be reset, and the client could lose the refusal). A client that does
    /// not close is closed at the idle timeout.
    fn poll_refuse_http2(&mut self, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        std::task::ready!(self.poll_answer(cx))?;
        let mut scratch = [0u8; 4096];
        loop {
            let mut dropped = ReadBuf::new(&mut scratch);
            match Pin::new(&mut self.inner).poll_read(cx, &mut dropped) {
                Poll::Pending => return self.poll_deadline(cx),
                Poll::Ready(Ok(())) if dropped.filled().is_empty() => return Poll::Ready(Ok(())),
                Poll::Ready(Ok(())) => {}
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
            }
        }
    }
}

impl AsyncWrite for LimitedIo {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_answer(cx))?;
        if let Some(n) = this.took_bare_error(cx, buf) {
            return Poll::Ready(Ok(n));
        }
        let written = Pin::new(&mut this.inner).poll_write(cx, buf);
        this.after_write(cx, written)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_answer(cx))?;
        if let Some(first) = bufs.iter().find(|b| !b.is_empty())
            && let Some(n) = this.took_bare_error(cx, first)
        {
            return Poll::Ready(Ok(n));
        }
        let written = Pin::new(&mut this.inner).poll_write_vectored(cx, bufs);
        this.after_write(cx, written)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_answer(cx))?;
        match Pin::new(&mut this.inner).poll_flush(cx) {
            Poll::Pending => this.poll_deadline(cx),
            ready => ready,
        }
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        std::task::ready!(this.poll_answer(cx))?;
        Pin::new(&mut this.inner).poll_shutdown(cx)
    }
}

/// Starts a [`Server`] over `built` with the default [`ServerConfig`] and serves on `listener`
/// (bind `127.0.0.1:0` for an ephemeral port).
pub async fn serve(
    listener: tokio::net::TcpListener,
    built: Arc<BuiltScene>,
    backend: Backend,
) -> Result<()> {
    let server =
        tokio::task::spawn_blocking(move || Server::new(built, backend, ServerConfig::default()))
            .await
            .map_err(|e| Error::Invalid(format!("starting the server failed: {e}")))??;
    server.serve(listener).await
}
