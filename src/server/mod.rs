//! `raypick serve`: an HTTP JSON API (axum on tokio) over one scene kept resident in a picker,
//! and the viewer page it serves.
//!
//! This module owns the [`Server`] (its configuration, start-up and serving); the routes and
//! their JSON live in `api`, the picking worker and its batching in [`batcher`], the page in
//! [`page`].
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
//! malformed JSON, unknown fields, a bad camera or option; 413 for a body over
//! [`ServerConfig::max_body_bytes`], more than [`ServerConfig::max_rays`] rays, or in mode `all`
//! more than [`ServerConfig::max_hit_entries`] rays x `max_hits`; 404; 405) and 500 when
//! picking itself fails.
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
//! `camera` is a camera file's JSON ([`crate::camera`]). Pixel coordinates are pixel
//! *indices*, as in pixel files ([`crate::camera::parse_pixel_indices_as_centers`]): `x` is the
//! column from the left, `y` the row from the top, integers name whole pixels and are picked
//! through their centres (`[3, 4]` is the ray through `(3.5, 4.5)`), fractional values are
//! offsets from that centre. Options, all optional: `mode` (`closest`, `any`, `all`), `cull`
//! (`none`, `back`, `front`), `max_hits` (mode `all`, 1 ..= 1024, default 16), `intersector`
//! (`watertight` or `moller-trumbore`; default [`crate::Intersector::default`]), and `tmin`,
//! `tmax`, `mask` as defaults for rays without their own (and for pixel rays); `tmax` absent
//! or `null` is unbounded. Numbers are read correctly rounded (serde_json's
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
//! The backend and device, the bounds, the objects (id, name, triangles, mask, grid shape),
//! the triangle count, the tree (nodes, leaves, depth, GPU bytes and bytes per triangle), the
//! framing camera the viewer starts from, the limits and the counters.
//!
//! ## `GET /render?camera=<url-encoded camera JSON>&shade=normal`
//!
//! A PNG of the view ([`crate::render`]); `shade` is `normal`, `depth` or `object`. Without
//! `camera`, the framing camera ([`crate::camera::Camera::frame_bounds`]) at `width` x `height`
//! (default [`ServerConfig::view_width`] x [`ServerConfig::view_height`]).
//!
//! ## `GET /stats`
//!
//! The worker's [`Stats`].
//!
//! ## `GET /`
//!
//! The viewer: the rendered view; click picks the pixel and shows the world position, object,
//! triangle and terrain cell; drag orbits around the target; the wheel zooms.

mod api;
pub mod batcher;
pub mod page;

pub use batcher::Stats;

use crate::error::{Error, Result};
use crate::picker::{Backend, BuiltScene};
use std::sync::Arc;
use std::time::Duration;

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
}

impl ServerConfig {
    /// The most all-hits list entries (`rays x max_hits`) one request may ask for in mode
    /// `all`: 16 per ray of [`ServerConfig::max_rays`], so that a request's hit lists stay
    /// within a bounded amount of memory.
    pub fn max_hit_entries(&self) -> usize {
        self.max_rays.saturating_mul(16)
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
    /// fails (no GPU adapter, a scene too large for the GPU).
    pub fn new(built: Arc<BuiltScene>, backend: Backend, config: ServerConfig) -> Result<Server> {
        let worker = batcher::Worker::start(
            built.clone(),
            backend,
            config.batch_window,
            (
                config.max_rays.saturating_mul(4),
                config.max_hit_entries().saturating_mul(4),
            ),
        )?;
        Ok(Server {
            state: Arc::new(api::AppState {
                worker,
                built,
                backend,
                config,
            }),
        })
    }

    /// What answers picks ([`crate::Picker::describe`]), e.g.
    /// `gpu llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan, Cpu)` or `cpu (2 threads)`.
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
    /// dropped.
    pub async fn serve(self, listener: tokio::net::TcpListener) -> Result<()> {
        let address = listener
            .local_addr()
            .map_or_else(|_| "the listener".to_owned(), |a| a.to_string());
        axum::serve(listener, self.router())
            .await
            .map_err(|source| Error::Io {
                path: address,
                source,
            })
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
