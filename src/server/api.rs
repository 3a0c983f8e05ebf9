//! The HTTP routes and their JSON: request parsing and checking, the response records, and
//! errors as `{"error": "sentence"}` with a 4xx/5xx status. The wire format is documented in
//! the [module docs](super).

use super::ServerConfig;
use super::batcher::{
    Edit, EditError, Job, JobError, MeshSource, SceneView, SharedView, Stats, Worker,
};
use super::object_only::ObjectOnly;
use super::page;
use crate::apps::camera::{Camera, CameraSpec};
use crate::apps::render::Shade;
use crate::names::Named;
use crate::picker::Backend;
use crate::query::{Answers, Cull, Intersector, MAX_HITS_LIMIT, Mode, Query};
use crate::ray::{Hit, Ray};
use axum::Router;
use axum::body::{Body, Bytes};
use axum::extract::rejection::QueryRejection;
use axum::extract::{Path as UrlPath, Query as UrlQuery, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, patch, post};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use tokio::sync::{OwnedSemaphorePermit, Semaphore, oneshot};

/// What every handler shares: the picking worker, the scene and the limits.
pub(crate) struct AppState {
    /// The picking worker.
    pub(crate) worker: Worker,
    /// The scene version the worker last published (it changes with each edit).
    pub(crate) view: SharedView,
    /// Which path answers picks.
    pub(crate) backend: Backend,
    /// Limits and defaults.
    pub(crate) config: ServerConfig,
    /// The memory budget of the requests in progress.
    pub(crate) memory: MemoryBudget,
}

/// Parsed request records per byte of request body, at most (ray records are about 2.7 times
/// their shortest JSON, and their vector may double while growing).
const PARSED_BYTES_PER_BODY_BYTE: u64 = 8;

/// Bytes of answer per result and per all-hits entry, at most: the answer record and its JSON.
const ANSWER_BYTES_PER_HIT: u64 = 512;

/// Reservations at least this large ask the allocator to return freed memory when they end.
const TRIM_AFTER_BYTES: u64 = 32 << 20;

/// The memory budget of the requests in progress ([`ServerConfig::memory_budget`]), kept as
/// KiB permits of a semaphore; requests wait for their memory in arrival order.
pub(crate) struct MemoryBudget {
    permits: Arc<Semaphore>,
    total_kib: u64,
    wait: Duration,
}

/// Memory reserved for one request; given back when dropped.
pub(crate) struct Reservation {
    _permit: OwnedSemaphorePermit,
    bytes: u64,
}

impl MemoryBudget {
    /// A budget of `bytes` (at least 1 KiB); requests wait up to `wait` for their share.
    pub(crate) fn new(bytes: u64, wait: Duration) -> Self {
        let most = (u32::MAX as u64).min(Semaphore::MAX_PERMITS as u64);
        let total_kib = (bytes / 1024).clamp(1, most);
        Self {
            permits: Arc::new(Semaphore::new(total_kib as usize)),
            total_kib,
            wait,
        }
    }

    /// Reserves `bytes` for `what` (e.g. "this pick"): waits for them up to the budget's wait
    /// time; 503 if they can never fit or did not become free in time.
    pub(crate) async fn reserve(&self, what: &str, bytes: u64) -> Result<Reservation, ApiError> {
        let kib = self.fits(what, bytes)?;
        Ok(Reservation {
            _permit: self.acquire(what, bytes, kib).await?,
            bytes,
        })
    }

    /// Grows `held` (this request's reservation so far) to `bytes` for `what`, as
    /// [`MemoryBudget::reserve`] would reserve them, except that the memory `held` covers goes
    /// on to the new use rather than being asked for again: a pick whose body and rays each fit
    /// the budget but not both together waited on its own body's reservation for the whole
    /// wait, then heard that the server was busy.
    pub(crate) async fn grow(
        &self,
        mut held: Reservation,
        what: &str,
        bytes: u64,
    ) -> Result<Reservation, ApiError> {
        let kib = self.fits(what, bytes)?;
        let held_kib = held._permit.num_permits() as u64;
        if kib > held_kib {
            let more = self.acquire(what, bytes, kib - held_kib).await?;
            held._permit.merge(more);
            held.bytes = bytes;
        }
        Ok(held)
    }

    /// The KiB permits of `bytes`; 503 if they can never fit the budget.
    pub(crate) fn fits(&self, what: &str, bytes: u64) -> Result<u64, ApiError> {
        let kib = bytes.div_ceil(1024).max(1);
        if kib > self.total_kib {
            return Err(ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "{what} would need about {} of memory, more than this server's budget of {} \
                     for all requests at once; send fewer rays, a smaller max_hits or a smaller \
                     image",
                    human(bytes),
                    human(self.total_kib * 1024)
                ),
            ));
        }
        Ok(kib)
    }

    /// `kib` permits for `what` (which needs `bytes` in all), waited for up to the budget's
    /// wait time; 503 if they did not become free in time.
    async fn acquire(
        &self,
        what: &str,
        bytes: u64,
        kib: u64,
    ) -> Result<OwnedSemaphorePermit, ApiError> {
        let acquire = self.permits.clone().acquire_many_owned(kib as u32);
        match tokio::time::timeout(self.wait, acquire).await {
            Ok(Ok(permit)) => Ok(permit),
            _ => Err(ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "the server is busy: {what} needs about {} of memory, and its budget of {} \
                     stayed in use by other requests for {} s; retry later",
                    human(bytes),
                    human(self.total_kib * 1024),
                    self.wait.as_secs_f64()
                ),
            )),
        }
    }
}

impl Reservation {
    /// The bytes its permits cover.
    fn bytes(&self) -> u64 {
        self._permit.num_permits() as u64 * 1024
    }

    /// Gives back what it holds past `bytes` (at least one KiB kept).
    fn shrink_to(&mut self, bytes: u64) {
        let keep = bytes.div_ceil(1024).max(1);
        let held = self._permit.num_permits() as u64;
        if held > keep {
            drop(self._permit.split((held - keep) as usize));
            self.bytes = self.bytes.min(keep * 1024);
        }
    }
}

impl Drop for Reservation {
    fn drop(&mut self) {
        if self.bytes >= TRIM_AFTER_BYTES {
            schedule_trim();
        }
    }
}

/// Soon asks the allocator to give freed memory back to the system (once for several large
/// requests ending together), so that the server's memory returns near idle after them.
fn schedule_trim() {
    static SCHEDULED: AtomicBool = AtomicBool::new(false);
    if SCHEDULED.swap(true, Ordering::SeqCst) {
        return;
    }
    match tokio::runtime::Handle::try_current() {
        Ok(runtime) => {
            runtime.spawn(async {
                // Let the answer be sent and freed first.
                tokio::time::sleep(Duration::from_millis(200)).await;
                SCHEDULED.store(false, Ordering::SeqCst);
                let _ = tokio::task::spawn_blocking(release_free_memory).await;
            });
        }
        Err(_) => {
            SCHEDULED.store(false, Ordering::SeqCst);
            release_free_memory();
        }
    }
}

/// Returns the allocator's free memory to the system (glibc's `malloc_trim`, every arena).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn release_free_memory() {
    unsafe extern "C" {
        fn malloc_trim(pad: usize) -> std::ffi::c_int;
    }
    // SAFETY: `malloc_trim` takes no pointers and is thread-safe; it only returns free pages.
    unsafe {
        malloc_trim(0);
    }
}

/// Elsewhere the allocator keeps its own policy.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn release_free_memory() {}

/// `bytes` for a message, in MiB or GiB.
fn human(bytes: u64) -> String {
    const MIB: f64 = (1u64 << 20) as f64;
    if bytes >= 1 << 30 {
        format!("{:.1} GiB", bytes as f64 / (MIB * 1024.0))
    } else if bytes < 1 << 20 {
        format!("{} KiB", bytes.div_ceil(1024))
    } else {
        format!("{:.1} MiB", bytes as f64 / MIB)
    }
}

/// The memory a pick of `rays` rays holds at most: the picker's per-ray memory
/// ([`Query::bytes_per_ray`], all-hits lists included) and the answer's records and JSON.
fn pick_bytes(rays: usize, query: &Query) -> u64 {
    let rays = rays as u64;
    let results = rays.saturating_mul(1 + u64::from(query.list_length()));
    rays.saturating_mul(query.bytes_per_ray())
        .saturating_add(results.saturating_mul(ANSWER_BYTES_PER_HIT))
}

/// The memory a render of `pixels` pixels holds at most: its rays and hits, its RGBA image and
/// its PNG.
fn render_bytes(pixels: u64) -> u64 {
    pixels.saturating_mul(Query::default().bytes_per_ray() + 8)
}

/// The routes over `state`.
pub(crate) fn router(state: Arc<AppState>) -> Router {
    Router::new()
        .route("/", get(page::viewer))
        .route("/pick", post(pick))
        .route("/scene", get(scene))
        .route("/stats", get(stats))
        .route("/render", get(render_view))
        .route("/objects", post(add_object))
        .route("/objects/{id}", patch(change_object).delete(remove_object))
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(axum::middleware::from_fn(super::origin::same_origin_only))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            super::host::known_hosts_only,
        ))
        .layer(axum::middleware::from_fn(
            super::unread_body::close_if_body_unread,
        ))
        .with_state(state)
}

/// An error answer: a status and a sentence, sent as `{"error": "sentence"}`.
#[derive(Debug)]
pub(crate) struct ApiError {
    status: StatusCode,
    message: String,
}

impl ApiError {
    pub(crate) fn new(status: StatusCode, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }

    fn bad_request(message: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, message)
    }

    fn too_large(message: impl Into<String>) -> Self {
        Self::new(StatusCode::PAYLOAD_TOO_LARGE, message)
    }

    fn internal(message: impl Into<String>) -> Self {
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, message)
    }

    /// A failed pick or render: 503 when it was over the memory budget, else 500.
    fn of_job(error: JobError) -> Self {
        let status = if error.over_budget {
            StatusCode::SERVICE_UNAVAILABLE
        } else if error.over_time {
            StatusCode::PAYLOAD_TOO_LARGE
        } else {
            StatusCode::INTERNAL_SERVER_ERROR
        };
        Self::new(status, error.message)
    }
}

/// The most characters of an error sentence sent back; longer ones are cut with "…".
const MOST_ERROR_CHARS: usize = 1000;

impl IntoResponse for ApiError {
    /// The sentence with every quoted or long token of the request in it (serde's and axum's
    /// rejections repeat a bad field name or value whole, of any size) cut to 60 characters
    /// and "…", as the command line cuts its messages.
    fn into_response(self) -> Response {
        let message = crate::error::shorten_tokens(
            &crate::error::shorten_quoted(&self.message),
            MOST_ERROR_CHARS,
        );
        json_response(self.status, &json!({ "error": message }))
    }
}

/// `value` as a JSON response with `status`.
fn json_response(status: StatusCode, value: &impl Serialize) -> Response {
    match serde_json::to_vec(value) {
        Ok(body) => (
            status,
            [(
                header::CONTENT_TYPE,
                HeaderValue::from_static("application/json"),
            )],
            body,
        )
            .into_response(),
        Err(e) => (
            StatusCode::INTERNAL_SERVER_ERROR,
            [(
                header::CONTENT_TYPE,
                HeaderValue::from_static("application/json"),
            )],
            format!("{{\"error\":\"the answer could not be written as JSON: {e}\"}}"),
        )
            .into_response(),
    }
}

async fn not_found() -> ApiError {
    ApiError::new(
        StatusCode::NOT_FOUND,
        "there is no such page; the API is GET /, GET /scene, GET /stats, GET /render, POST /pick, POST /objects, PATCH /objects/{id} and DELETE /objects/{id}",
    )
}

async fn method_not_allowed() -> ApiError {
    ApiError::new(
        StatusCode::METHOD_NOT_ALLOWED,
        "this path does not take that method: /pick and /objects take POST; /objects/{id} takes PATCH and DELETE; /, /scene, /stats and /render take GET",
    )
}

/// The body of a `POST /pick`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PickRequest {
    /// Explicit world rays.
    rays: Option<Vec<ObjectOnly<RayRequest>>>,
    /// A camera whose `pixels` are picked.
    camera: Option<CameraSpec>,
    /// Pixel indices `[x, y]` of `camera` (integers name whole pixels, picked at their centres).
    pixels: Option<Vec<[f64; 2]>>,
    #[serde(default)]
    mode: Mode,
    #[serde(default)]
    cull: Cull,
    max_hits: Option<u32>,
    intersector: Option<String>,
    /// Default `tmin` for rays without one, and for pixel rays.
    tmin: Option<f64>,
    /// Default `tmax` (`null` or absent: unbounded).
    tmax: Option<f64>,
    /// Default layer mask (`ray_mask`, as the command line names it, is accepted too).
    #[serde(alias = "ray_mask")]
    mask: Option<u32>,
}

/// One ray of a `POST /pick`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RayRequest {
    origin: [f64; 3],
    dir: [f64; 3],
    tmin: Option<f64>,
    tmax: Option<f64>,
    #[serde(alias = "ray_mask")]
    mask: Option<u32>,
}

impl PickRequest {
    /// The rays and query this request asks for, checked against `config`'s ray limit.
    fn into_rays(self, config: &ServerConfig) -> Result<(Vec<Ray>, Query), ApiError> {
        let intersector = match self.intersector.as_deref() {
            None => Intersector::default(),
            Some(name) => Intersector::from_name(name).ok_or_else(|| {
                ApiError::bad_request(format!(
                    "unknown intersector '{}'; expected 'moller-trumbore' or 'watertight'",
                    crate::budget::quote(name)
                ))
            })?,
        };
        // Checked in every mode, as the command line and Python check it: a max_hits out of
        // range is a mistake whether or not this mode reads it.
        if let Some(max_hits) = self.max_hits
            && !(1..=MAX_HITS_LIMIT).contains(&max_hits)
        {
            return Err(ApiError::bad_request(format!(
                "max_hits {max_hits} is out of range; it must be 1 ..= {MAX_HITS_LIMIT}"
            )));
        }
        let query = Query {
            mode: self.mode,
            cull: self.cull,
            max_hits: self.max_hits.unwrap_or(Query::default().max_hits),
            intersector,
        };
        query
            .validate()
            .map_err(|e| ApiError::bad_request(e.to_string()))?;
        let tmin = self.tmin.unwrap_or(0.0);
        let tmax = self.tmax.unwrap_or(f64::INFINITY);
        let mask = self.mask.unwrap_or(u32::MAX);
        let check_count = |count: usize| {
            if count > config.max_rays {
                return Err(ApiError::too_large(format!(
                    "the request has {count} rays, more than this server's limit of {} per \
                     request; split it into several requests",
                    config.max_rays
                )));
            }
            let entries = count.saturating_mul(query.list_length() as usize);
            if entries > config.max_hit_entries() {
                return Err(ApiError::too_large(format!(
                    "mode all with max_hits {} over {count} rays could keep {entries} hits, more \
                     than this server's limit of {} per request; lower max_hits or send fewer \
                     rays",
                    query.max_hits,
                    config.max_hit_entries()
                )));
            }
            Ok(())
        };
        let rays = match (self.rays, self.camera, self.pixels) {
            (Some(rays), None, None) => {
                check_count(rays.len())?;
                rays.into_iter()
                    .map(|ObjectOnly(r)| {
                        Ray::new(DVec3::from_array(r.origin), DVec3::from_array(r.dir))
                            .with_range(r.tmin.unwrap_or(tmin), r.tmax.unwrap_or(tmax))
                            .with_mask(r.mask.unwrap_or(mask))
                    })
                    .collect()
            }
            (None, Some(spec), Some(pixels)) => {
                check_count(pixels.len())?;
                let camera =
                    Camera::from_spec(spec).map_err(|e| ApiError::bad_request(e.to_string()))?;
                pixels
                    .into_iter()
                    .map(|[x, y]| {
                        camera
                            .pixel_ray(x + 0.5, y + 0.5)
                            .with_range(tmin, tmax)
                            .with_mask(mask)
                    })
                    .collect()
            }
            (None, Some(_), None) => {
                return Err(ApiError::bad_request(
                    "the request has a `camera` but no `pixels`: give the pixels to pick as \
                     [[x, y], ...]",
                ));
            }
            (None, None, Some(_)) => {
                return Err(ApiError::bad_request(
                    "the request has `pixels` but no `camera` to turn them into rays",
                ));
            }
            (Some(_), _, _) => {
                return Err(ApiError::bad_request(
                    "the request has both `rays` and a camera: give either `rays`, or \
                     `camera` with `pixels`",
                ));
            }
            (None, None, None) => {
                return Err(ApiError::bad_request(
                    "the request has no rays: give `rays` ([{\"origin\": [x, y, z], \"dir\": \
                     [x, y, z]}, ...]), or `camera` and `pixels`",
                ));
            }
        };
        Ok((rays, query))
    }
}

/// The memory reserved for a body before any of it arrives, and the least a reservation grows
/// by as it does: a client that declares a large body and sends nothing holds this much, not
/// what it declared (42 such uploads held a 2.9 GiB budget for the body timeout, and every
/// other request got 503).
const BODY_RESERVE_STEP: u64 = 64 * 1024;

/// Reads a request body of at most `limit` bytes, which must arrive whole within `timeout`
/// (408 otherwise; a larger one is refused with `advice`, what to send instead), reserving its
/// memory from `memory` for `what` ("this pick's body") as it arrives, and then what its
/// records take once parsed ([`PARSED_BYTES_PER_BODY_BYTE`]): the body, and its reservation. A
/// body whose declared length could never fit the budget parsed is refused (503) before any of
/// it is read.
async fn read_body(
    memory: &MemoryBudget,
    headers: &HeaderMap,
    body: Body,
    (limit, timeout): (usize, Duration),
    advice: &str,
    what: &str,
) -> Result<(Bytes, Reservation), ApiError> {
    let too_large = || {
        ApiError::too_large(format!(
            "the request body is larger than this server's limit of {limit} bytes; {advice}"
        ))
    };
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|s| s.trim().parse::<u64>().ok());
    if declared.is_some_and(|n| n > limit as u64) {
        return Err(too_large());
    }
    // A compressed body would be read as JSON and refused for its bytes: say why instead.
    if let Some(coding) = headers
        .get(header::CONTENT_ENCODING)
        .filter(|v| !v.as_bytes().eq_ignore_ascii_case(b"identity"))
    {
        return Err(ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            format!(
                "the request body is sent with Content-Encoding {}, which this server does not \
                 read; send it uncompressed",
                crate::budget::quote(&String::from_utf8_lossy(coding.as_bytes()))
            ),
        ));
    }
    if let Some(n) = declared {
        memory.fits(what, n.saturating_mul(1 + PARSED_BYTES_PER_BODY_BYTE))?;
    }
    // What arrives is reserved as it does: a declared small body its own size, others a
    // first share.
    let first = declared.map_or(BODY_RESERVE_STEP, |n| n.clamp(1, BODY_RESERVE_STEP));
    let held = memory.reserve(what, first).await?;
    let read = async move {
        let (mut body, mut held) = (body, held);
        // Room for what was reserved first, where the body said its size.
        let mut data: Vec<u8> = Vec::with_capacity(declared.map_or(0, |_| first as usize));
        while let Some(frame) = std::future::poll_fn(|cx| {
            http_body::Body::poll_frame(std::pin::Pin::new(&mut body), cx)
        })
        .await
        {
            let Ok(chunk) = frame.map_err(|e| body_error(e, too_large))?.into_data() else {
                continue;
            };
            let length = data.len() + chunk.len();
            if length > limit {
                return Err(too_large());
            }
            if length as u64 > held.bytes() {
                let more = (length as u64).max(held.bytes().saturating_mul(2));
                held = memory.grow(held, what, more.min(limit as u64)).await?;
            }
            data.extend_from_slice(&chunk);
        }
        Ok((data, held))
    };
    let (data, held) = tokio::time::timeout(timeout, read).await.map_err(|_| {
        ApiError::new(
            StatusCode::REQUEST_TIMEOUT,
            format!(
                "the request body did not arrive whole within {} s; send it at once",
                timeout.as_secs_f64()
            ),
        )
    })??;
    let parsed = (data.len() as u64).saturating_mul(1 + PARSED_BYTES_PER_BODY_BYTE);
    let mut held = memory.grow(held, what, parsed).await?;
    // What the reads' doubling reserved past that goes back.
    held.shrink_to(parsed);
    Ok((Bytes::from(data), held))
}

/// A body that could not be read: `too_large()` for one over a limit anywhere in the error's
/// chain, else 400 with hyper's outer words ("error reading a body from connection"), which name no
/// cause, and the chain's own (a chunk's size line that is not hexadecimal, say).
fn body_error(e: axum::Error, too_large: impl Fn() -> ApiError) -> ApiError {
    let mut words: Vec<String> = Vec::new();
    let mut source: Option<&dyn std::error::Error> = Some(&e);
    while let Some(err) = source {
        let text = err.to_string();
        if text.contains("length limit exceeded") {
            return too_large();
        }
        if !words.iter().any(|w| w.contains(&text)) {
            words.push(text);
        }
        source = err.source();
    }
    words.truncate(3);
    ApiError::bad_request(format!(
        "the request body could not be read: {}",
        words.join(": ")
    ))
}

/// Bodies past this many bytes are parsed on the blocking pool ([`maybe_blocking`]).
const LARGE_BODY_BYTES: usize = 256 << 10;

/// Answers of more rays than this are written on the blocking pool ([`maybe_blocking`]).
const LARGE_ANSWER_RAYS: usize = 4096;

/// Runs `work` on the blocking pool when it is `large` (seconds of CPU for the largest bodies
/// and answers: parsing 8 MiB of JSON, writing hundreds of MB), so the runtime's threads go on
/// serving other connections meanwhile (two large picks held `GET /stats` for 3–6 s); small
/// work runs here, without the hand-over. Work that holds memory takes its reservation with it
/// and gives it back in its result: a blocking task runs on when its client has left.
async fn maybe_blocking<T: Send + 'static>(
    large: bool,
    work: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
) -> Result<T, ApiError> {
    if !large {
        return work();
    }
    tokio::task::spawn_blocking(work)
        .await
        .map_err(|e| ApiError::internal(format!("the request's work failed: {e}")))?
}

/// `POST /pick`.
async fn pick(
    State(state): State<Arc<AppState>>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let limits = (state.config.max_body_bytes, state.config.body_timeout);
    let advice = "send fewer rays per request";
    let (bytes, body_memory) = read_body(
        &state.memory,
        &headers,
        body,
        limits,
        advice,
        "this pick's body",
    )
    .await?;
    let config = state.clone();
    let large = bytes.len() > LARGE_BODY_BYTES;
    // The reservation goes with the work: a blocking task runs on when its client has left.
    let ((rays, query), body_memory) = maybe_blocking(large, move || {
        let request: PickRequest = parse_body(&bytes, "pick request")?;
        drop(bytes);
        Ok((request.into_rays(&config.config)?, body_memory))
    })
    .await?;
    // The body is gone (its records are the rays now): its memory goes on to the pick, and
    // stays reserved until the answer has been sent.
    let pick_memory = state
        .memory
        .grow(
            body_memory,
            &format!("this pick of {} rays", rays.len()),
            pick_bytes(rays.len(), &query),
        )
        .await?;
    let answers = if rays.is_empty() {
        empty_answers(query.mode)
    } else {
        let (reply, answer) = oneshot::channel();
        state
            .worker
            .submit(Job::Pick { rays, query, reply })
            .map_err(ApiError::internal)?;
        answer
            .await
            .map_err(|_| ApiError::internal("the picking worker dropped the request"))?
            .map_err(ApiError::of_job)?
    };
    let view = state.view();
    let large = answers.nearest.len() > LARGE_ANSWER_RAYS;
    let (json, pick_memory) = maybe_blocking(large, move || {
        let names: Vec<&str> = view.objects.iter().map(|o| public_name(&o.name)).collect();
        let written = if query.mode == Mode::All {
            let results: Vec<ListOut> = (0..answers.nearest.len())
                .map(|i| ListOut {
                    invalid: answers.nearest[i].invalid,
                    overflow: answers.overflow.get(i).copied().unwrap_or(false),
                    hits: answers
                        .hits_of(i)
                        .iter()
                        .map(|h| HitOut::new(h, &names))
                        .collect(),
                })
                .collect();
            serde_json::to_vec(&PickResponse { results })
        } else {
            let results: Vec<HitOut> = answers
                .nearest
                .iter()
                .map(|h| HitOut::new(h, &names))
                .collect();
            serde_json::to_vec(&PickResponse { results })
        };
        let json = written.map_err(|e| {
            ApiError::internal(format!("the answer could not be written as JSON: {e}"))
        })?;
        Ok((json, pick_memory))
    })
    .await?;
    Ok((
        StatusCode::OK,
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        super::held_body::holding(json, pick_memory),
    )
        .into_response())
}

/// An object's name as answers show it: the file name without its folders, so answers never
/// reveal the server's paths. Objects are named by their file's path (`dir/dem.asc`), or for
/// glTF `<path>#<mesh>/<primitive>` (`dir/city.glb#roof/0` shows as `city.glb#roof/0`); names
/// without a folder (the example scene's `tower`) are kept.
pub(crate) fn public_name(name: &str) -> &str {
    let lower = name.to_ascii_lowercase();
    // A glTF object: the path ends where `.gltf#` or `.glb#` does (the first such place).
    let path_end = [".gltf#", ".glb#"]
        .iter()
        .filter_map(|ext| lower.find(ext).map(|at| at + ext.len() - 1))
        .min()
        .unwrap_or(name.len());
    let path = &name[..path_end];
    let file_start = path.rfind(['/', '\\']).map_or(0, |at| at + 1);
    &name[file_start..]
}

/// Answers for zero rays.
fn empty_answers(mode: Mode) -> Answers {
    Answers {
        list_start: if mode == Mode::All { vec![0] } else { vec![] },
        ..Answers::default()
    }
}

/// The body of a pick answer.
#[derive(Serialize)]
struct PickResponse<T> {
    results: Vec<T>,
}

/// One hit (or miss) as JSON.
#[derive(Serialize)]
struct HitOut<'a> {
    hit: bool,
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    invalid: bool,
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    details: Option<HitDetails<'a>>,
}

/// Where a hit is.
#[derive(Serialize)]
struct HitDetails<'a> {
    t: f64,
    object: u32,
    object_name: &'a str,
    triangle: u32,
    u: f64,
    v: f64,
    position: [f64; 3],
    normal: [f64; 3],
    #[serde(skip_serializing_if = "Option::is_none")]
    row: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    col: Option<u32>,
}

impl<'a> HitOut<'a> {
    fn new(hit: &Hit, names: &[&'a str]) -> Self {
        Self {
            hit: hit.hit,
            invalid: hit.invalid,
            details: hit.hit.then(|| HitDetails {
                t: hit.t,
                object: hit.object,
                object_name: names.get(hit.object as usize).copied().unwrap_or(""),
                triangle: hit.triangle,
                u: hit.u,
                v: hit.v,
                position: hit.position.to_array(),
                normal: hit.normal.to_array(),
                row: hit.cell.map(|c| c[0]),
                col: hit.cell.map(|c| c[1]),
            }),
        }
    }
}

/// One ray's all-hits answer as JSON.
#[derive(Serialize)]
struct ListOut<'a> {
    hits: Vec<HitOut<'a>>,
    overflow: bool,
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    invalid: bool,
}

/// `GET /scene`.
async fn scene(State(state): State<Arc<AppState>>) -> Response {
    let view = state.view();
    let triangles = view.triangles;
    let objects: Vec<_> = view
        .objects
        .iter()
        .filter(|o| !o.removed)
        .map(|o| {
            json!({
                "id": o.id,
                "name": public_name(&o.name),
                "triangles": o.triangles,
                "mask": o.mask,
                "grid": o.grid.map(|g| json!({"columns": g.columns, "rows": g.rows})),
                "transform": o.transform,
            })
        })
        .collect();
    let bounds = view
        .bounds
        .map(|(lo, hi)| json!({"min": lo.to_array(), "max": hi.to_array()}));
    let (nodes, leaves, depth, gpu_bytes) = view.tree;
    json_response(
        StatusCode::OK,
        &json!({
            "backend": state.backend.name(),
            "device": state.worker.description(),
            "bounds": bounds,
            "origin": view.origin.to_array(),
            "triangles": triangles,
            "objects": objects,
            "tree": {
                "nodes": nodes,
                "leaves": leaves,
                "depth": depth,
                "gpu_bytes": gpu_bytes,
                "gpu_bytes_per_triangle": (view.tree_triangles > 0)
                    .then(|| gpu_bytes as f64 / view.tree_triangles as f64),
            },
            "camera": default_camera(&state, None),
            "limits": {
                "max_body_bytes": state.config.max_body_bytes,
                "max_rays": state.config.max_rays,
                "max_connections": state.config.max_connections,
                "memory_budget": state.config.memory_budget,
                "idle_timeout_s": state.config.idle_timeout.as_secs_f64(),
                "body_timeout_s": state.config.body_timeout.as_secs_f64(),
            },
            "stats": state.worker.stats(),
        }),
    )
}

/// The framing camera of the scene ([`Camera::frame_bounds`]), at `size` or the configured
/// view size.
fn default_camera(state: &AppState, size: Option<(u32, u32)>) -> Camera {
    let (width, height) = size.unwrap_or((state.config.view_width, state.config.view_height));
    let (lo, hi) = state
        .view()
        .bounds
        .unwrap_or((DVec3::INFINITY, DVec3::NEG_INFINITY));
    Camera::frame_bounds(lo, hi, width, height)
}

impl AppState {
    /// The scene version the worker last published.
    pub(crate) fn view(&self) -> Arc<SceneView> {
        self.view
            .lock()
            .map(|v| v.clone())
            .unwrap_or_else(|e| e.into_inner().clone())
    }
}

/// `POST /objects`: `{"mesh": id}` (a copy of that object's mesh, as it was loaded or added)
/// or `{"vertices": [[x, y, z], …], "triangles": [[i, j, k], …]}`, with an optional
/// `"transform"` (3 × 4 row-major, applied to that mesh) and `"mask"`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AddRequest {
    mesh: Option<u32>,
    vertices: Option<Vec<[f64; 3]>>,
    triangles: Option<Vec<[u32; 3]>>,
    #[serde(default, deserialize_with = "crate::scene::transform_rows")]
    transform: Option<[[f64; 4]; 3]>,
    mask: Option<u32>,
}

/// `PATCH /objects/{id}`: a new `"transform"` (relative to the object as it was loaded or
/// added) and/or `"mask"`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ChangeRequest {
    #[serde(default, deserialize_with = "crate::scene::transform_rows")]
    transform: Option<[[f64; 4]; 3]>,
    mask: Option<u32>,
}

/// Reads a JSON edit body within the body limit and the memory budget.
async fn edit_body<T: serde::de::DeserializeOwned + Send + 'static>(
    state: &AppState,
    headers: &HeaderMap,
    body: Body,
    what: &'static str,
) -> Result<T, ApiError> {
    let limits = (state.config.max_body_bytes, state.config.body_timeout);
    let advice = "send a smaller mesh, or add it in parts";
    let (bytes, memory) = read_body(
        &state.memory,
        headers,
        body,
        limits,
        advice,
        &format!("this {what}'s body"),
    )
    .await?;
    let large = bytes.len() > LARGE_BODY_BYTES;
    maybe_blocking(large, move || {
        let parsed = parse_body(&bytes, what);
        drop((bytes, memory));
        parsed
    })
    .await
}

/// A JSON request body as `T`, or 400 with a sentence naming where it went wrong: the field's
/// path (`rays[3].origin[2]`) where there is one, then serde's reason and the place in the
/// body.
fn parse_body<T: serde::de::DeserializeOwned>(bytes: &[u8], what: &str) -> Result<T, ApiError> {
    let bad = |reason: String| {
        ApiError::bad_request(format!("the request body is not a valid {what}: {reason}"))
    };
    // serde takes a struct's fields from an array too, in order: a body is an object.
    match bytes.iter().find(|b| !b.is_ascii_whitespace()) {
        Some(b'{') | None => {}
        Some(_) => return Err(bad("it must be a JSON object ({…})".to_owned())),
    }
    let mut json = serde_json::Deserializer::from_slice(bytes);
    let value: T = serde_path_to_error::deserialize(&mut json).map_err(|e| {
        let path = e.path().to_string();
        let reason = e.into_inner().to_string();
        // An unknown field's own name ends the path and is in serde's sentence already.
        let path = match reason.starts_with("unknown field") {
            true => path.rsplit_once('.').map_or("", |(parent, _)| parent),
            false => path.as_str(),
        };
        // serde_path_to_error's `?` is a place it could not name (the body ended before a
        // field's name was read): the path is what comes before it.
        let path = path.strip_suffix(".?").unwrap_or(path);
        let path = if path == "?" { "" } else { path };
        let reason = field_reason(path, reason);
        match path {
            "" | "." => bad(reason),
            // A field name is the client's token: quoted, and cut as every token is.
            _ => bad(format!("`{}`: {reason}", crate::budget::quote(path))),
        }
    })?;
    json.end().map_err(|e| bad(e.to_string()))?;
    Ok(value)
}

/// serde_json's reason for a field, said in the request's terms where its own words name
/// nothing: "trailing characters" (inside a body, an array with more values than the field
/// takes) and "expected value" (a name or a camera given as something else, or what is no JSON
/// value, such as NaN).
fn field_reason(path: &str, reason: String) -> String {
    let field = path.rsplit(['.', '[']).next().unwrap_or(path);
    let takes = match field {
        "mode" => "one of \"closest\", \"any\", \"all\"",
        "cull" => "one of \"none\", \"back\", \"front\"",
        "camera" => "an object with exactly one of perspective, orthographic or matrices",
        // Elsewhere serde_json says it of what is no JSON value at all (Python's json.dumps
        // writes NaN and Infinity).
        _ => "a JSON value (NaN and Infinity are not JSON)",
    };
    if path.is_empty() || path == "." {
        return reason;
    }
    if let Some(rest) = reason.strip_prefix("trailing characters") {
        return format!("more values than it takes{rest}");
    }
    if let Some(rest) = reason.strip_prefix("expected value") {
        return format!("expected {takes}{rest}");
    }
    reason
}

/// Checks a transform from a request.
fn request_transform(transform: Option<[[f64; 4]; 3]>) -> Result<Option<[[f64; 4]; 3]>, ApiError> {
    if let Some(t) = &transform {
        crate::scene::check_transform(t)
            .map_err(|why| ApiError::bad_request(format!("the transform {why}")))?;
    }
    Ok(transform)
}

/// The object id in a path, written as ids are (`0`, `17`: digits, no sign, no leading zero),
/// or 404: `+1` and `001` name no object (Rust's parse took them for object 1).
fn object_id(id: &str) -> Result<u32, ApiError> {
    let canonical = !id.is_empty()
        && id.bytes().all(|b| b.is_ascii_digit())
        && (id == "0" || !id.starts_with('0'));
    canonical
        .then(|| id.parse::<u32>().ok())
        .flatten()
        .ok_or_else(|| {
            ApiError::new(
                StatusCode::NOT_FOUND,
                format!("there is no object \"{}\"", crate::budget::quote(id)),
            )
        })
}

/// Hands `edit` to the worker and answers `{"object": id}`, with `"warnings"` (sentences) where
/// the object now lies where it is picked less exactly.
async fn submit_edit(state: &AppState, edit: Edit) -> Result<Response, ApiError> {
    let (reply, answer) = oneshot::channel();
    state
        .worker
        .submit(Job::Edit { edit, reply })
        .map_err(ApiError::internal)?;
    let edited = answer
        .await
        .map_err(|_| ApiError::internal("the picking worker dropped the edit"))?
        .map_err(|e| match e {
            EditError::NotFound(m) => ApiError::new(StatusCode::NOT_FOUND, m),
            EditError::TooLarge(m) => ApiError::too_large(m),
            EditError::Failed(m) => ApiError::internal(m),
            EditError::Invalid(m) => ApiError::bad_request(m),
            EditError::OverBudget(m) => ApiError::new(StatusCode::SERVICE_UNAVAILABLE, m),
        })?;
    // Warnings only where there are some: most answers stay `{"object": id}`.
    let body = match edited.warnings.is_empty() {
        true => json!({ "object": edited.object }),
        false => json!({ "object": edited.object, "warnings": edited.warnings }),
    };
    Ok(json_response(StatusCode::OK, &body))
}

/// `POST /objects`.
async fn add_object(
    State(state): State<Arc<AppState>>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let request: AddRequest = edit_body(&state, &headers, body, "object").await?;
    let mesh = match (request.mesh, request.vertices, request.triangles) {
        (Some(id), None, None) => MeshSource::Copy(id),
        (None, Some(_), Some(triangles)) if triangles.is_empty() => {
            return Err(ApiError::bad_request(
                "an inline mesh needs at least one triangle",
            ));
        }
        (None, Some(vertices), Some(triangles)) if vertices.len() > 3 * triangles.len() => {
            return Err(ApiError::bad_request(format!(
                "an inline mesh has {} vertices for {} triangles; it may have at most three per \
                 triangle",
                vertices.len(),
                triangles.len()
            )));
        }
        (None, Some(vertices), Some(triangles)) => {
            if let Some((i, v)) = vertices
                .iter()
                .enumerate()
                .find(|(_, v)| !v.iter().all(|x| x.is_finite()))
            {
                return Err(ApiError::bad_request(format!(
                    "vertex {i} has a coordinate that is not finite: {v:?}"
                )));
            }
            MeshSource::Inline(crate::scene::Mesh {
                positions: vertices.into_iter().map(DVec3::from).collect(),
                triangles,
            })
        }
        _ => {
            return Err(ApiError::bad_request(
                "an object needs either \"mesh\" (the id of an object whose mesh to copy) or both \"vertices\" and \"triangles\"",
            ));
        }
    };
    let edit = Edit::Add {
        mesh,
        transform: request_transform(request.transform)?,
        mask: request.mask,
    };
    submit_edit(&state, edit).await
}

/// `PATCH /objects/{id}`.
async fn change_object(
    State(state): State<Arc<AppState>>,
    UrlPath(id): UrlPath<String>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let object = object_id(&id)?;
    let request: ChangeRequest = edit_body(&state, &headers, body, "object change").await?;
    if request.transform.is_none() && request.mask.is_none() {
        return Err(ApiError::bad_request(
            "a change needs \"transform\", \"mask\" or both",
        ));
    }
    let edit = Edit::Change {
        object,
        transform: request_transform(request.transform)?,
        mask: request.mask,
    };
    submit_edit(&state, edit).await
}

/// `DELETE /objects/{id}`.
async fn remove_object(
    State(state): State<Arc<AppState>>,
    UrlPath(id): UrlPath<String>,
) -> Result<Response, ApiError> {
    let object = object_id(&id)?;
    submit_edit(&state, Edit::Remove { object }).await
}

/// `GET /stats`.
async fn stats(State(state): State<Arc<AppState>>) -> Response {
    let stats: Stats = state.worker.stats();
    json_response(StatusCode::OK, &stats)
}

/// The query string of `GET /render`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RenderParams {
    /// Camera JSON (a [`CameraSpec`]).
    camera: Option<String>,
    /// `normal`, `depth` or `object`.
    shade: Option<String>,
    /// Image width of the framing camera (without `camera`; read by [`pixel_count`]).
    width: Option<String>,
    /// Image height of the framing camera (without `camera`).
    height: Option<String>,
    /// Ignored: a page adds its own count of scene edits so that it asks again after one.
    #[allow(dead_code, reason = "accepted and ignored")]
    version: Option<String>,
}

/// A `/render` image size parameter: a whole number of pixels, or 400 quoting it (the query's
/// own parse said "width: invalid digit found in string" for `width=-1`).
fn pixel_count(name: &str, text: &str) -> Result<u32, ApiError> {
    text.parse::<u32>().map_err(|e| {
        // A whole number past u32 said it was not one.
        let what = match e.kind() {
            std::num::IntErrorKind::PosOverflow => format!("more pixels than {}", u32::MAX),
            _ => "not a whole number of pixels".to_owned(),
        };
        ApiError::bad_request(format!("{name} '{}' is {what}", crate::budget::quote(text)))
    })
}

/// `GET /render`.
async fn render_view(
    State(state): State<Arc<AppState>>,
    params: Result<UrlQuery<RenderParams>, QueryRejection>,
) -> Result<Response, ApiError> {
    let UrlQuery(params) = params.map_err(|e| {
        ApiError::bad_request(format!(
            "the /render query is not valid: {}; it takes camera (camera JSON), shade \
             (normal, depth or object), width and height",
            e.body_text()
        ))
    })?;
    let shade = match params.shade.as_deref() {
        None => Shade::default(),
        Some(name) => Shade::from_name(name).ok_or_else(|| {
            ApiError::bad_request(format!(
                "unknown shade '{}'; expected normal, depth or object",
                crate::budget::quote(name)
            ))
        })?,
    };
    let width = params
        .width
        .as_deref()
        .map(|w| pixel_count("width", w))
        .transpose()?;
    let height = params
        .height
        .as_deref()
        .map(|h| pixel_count("height", h))
        .transpose()?;
    let camera = match (&params.camera, width, height) {
        (Some(text), None, None) => Camera::from_json_str("camera", text)
            .map_err(|e| ApiError::bad_request(e.to_string()))?,
        (Some(_), _, _) => {
            return Err(ApiError::bad_request(
                "give the image size inside the camera JSON, not as width/height parameters",
            ));
        }
        (None, width, height) => {
            let (width, height) = (
                width.unwrap_or(state.config.view_width),
                height.unwrap_or(state.config.view_height),
            );
            if width == 0 || height == 0 {
                return Err(ApiError::bad_request(format!(
                    "the image is {width} x {height} pixels; width and height must be at least 1"
                )));
            }
            default_camera(&state, Some((width, height)))
        }
    };
    let pixels = u64::from(camera.width()) * u64::from(camera.height());
    if pixels > state.config.max_rays as u64 {
        return Err(ApiError::too_large(format!(
            "the image has {pixels} pixels, more than this server's limit of {} rays per request",
            state.config.max_rays
        )));
    }
    let memory = state
        .memory
        .reserve(
            &format!("this render of {pixels} pixels"),
            render_bytes(pixels),
        )
        .await?;
    let (reply, answer) = oneshot::channel();
    state
        .worker
        .submit(Job::Render {
            camera: Box::new(camera),
            shade,
            reply,
        })
        .map_err(ApiError::internal)?;
    let image = answer
        .await
        .map_err(|_| ApiError::internal("the picking worker dropped the request"))?
        .map_err(ApiError::of_job)?;
    // The reservation goes with the encoding, and then with the PNG until it has been sent.
    let (png, memory) = tokio::task::spawn_blocking(move || (image.to_png(), memory))
        .await
        .map_err(|e| ApiError::internal(format!("encoding the PNG failed: {e}")))?;
    let png = png.map_err(|e| ApiError::internal(format!("encoding the PNG failed: {e}")))?;
    Ok((
        StatusCode::OK,
        [
            (header::CONTENT_TYPE, HeaderValue::from_static("image/png")),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-store")),
        ],
        super::held_body::holding(png, memory),
    )
        .into_response())
}
