//! The picking worker: one thread owns the picker (GPU or CPU) for the server's lifetime. Jobs
//! reach it over a channel; the pick jobs that arrive together (queued while it was busy, or
//! within the batch window after the first) are answered by ONE [`Picker::query`] call per
//! query settings, and the answers are split back to each job. The worker also renders views,
//! since only it may touch the picker, and keeps the [`Stats`] counters.

use crate::apps::camera::Camera;
use crate::apps::render::{Image, Shade, render};
use crate::error::{Error, Result};
use crate::picker::{Backend, BuiltScene, Picker};
use crate::query::{Answers, Mode, Query};
use crate::ray::Ray;
use serde::Serialize;
use std::ops::Range;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender, TryRecvError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::oneshot;

/// Counters of the work the picking worker has done since the server started.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Stats {
    /// Pick requests answered (successfully or not) by the worker; requests refused before
    /// picking, and requests with no rays, are not counted.
    pub pick_requests: u64,
    /// Rays in those requests.
    pub rays: u64,
    /// [`Picker::query`] calls made for them: one per query-settings group of each batch.
    pub batches: u64,
    /// Pick requests that shared their query call with at least one other request.
    pub batched_requests: u64,
    /// The most requests answered by one query call.
    pub largest_batch: u64,
    /// Views rendered.
    pub renders: u64,
}

/// A reply: the value, or a sentence saying why the worker could not produce it.
pub(crate) type Reply<T> = oneshot::Sender<std::result::Result<T, String>>;

/// Work for the picking worker.
pub(crate) enum Job {
    /// Answer `rays` as `query` asks.
    Pick {
        /// The rays, in the request's order.
        rays: Vec<Ray>,
        /// The settings; jobs with equal settings share one query call.
        query: Query,
        /// Where the answers go.
        reply: Reply<Answers>,
    },
    /// Render `camera`'s view.
    Render {
        /// The view.
        camera: Box<Camera>,
        /// How pixels are coloured.
        shade: Shade,
        /// Where the image goes.
        reply: Reply<Image>,
    },
}

impl Job {
    /// Rays this job traces and all-hits list entries it keeps (for the batch size caps).
    fn size(&self) -> (usize, usize) {
        match self {
            Job::Pick { rays, query, .. } => (
                rays.len(),
                rays.len().saturating_mul(query.list_length() as usize),
            ),
            Job::Render { camera, .. } => (camera.width() as usize * camera.height() as usize, 0),
        }
    }
}

/// The handle to a running picking worker; the worker stops when the last handle is dropped.
#[derive(Clone)]
pub(crate) struct Worker {
    sender: Sender<Job>,
    stats: Arc<Mutex<Stats>>,
    description: String,
}

impl Worker {
    /// Starts the worker thread, which builds the picker for `backend` over `built` and then
    /// waits for jobs. A batch stops growing once it holds `caps.0` rays or `caps.1` all-hits
    /// list entries (its first job is always taken). Blocks until the picker is ready; fails as
    /// building it fails (no GPU adapter, scene too large for the GPU, ...).
    pub(crate) fn start(
        built: Arc<BuiltScene>,
        backend: Backend,
        window: Duration,
        caps: (usize, usize),
    ) -> Result<Worker> {
        let (sender, receiver) = mpsc::channel::<Job>();
        let (ready_tx, ready_rx) = mpsc::sync_channel::<Result<String>>(1);
        let stats = Arc::new(Mutex::new(Stats::default()));
        let worker_stats = stats.clone();
        std::thread::Builder::new()
            .name("raypick-picker".into())
            .spawn(move || {
                let made = catch_unwind(AssertUnwindSafe(|| make_picker(backend, built)))
                    .unwrap_or_else(|_| Err(Error::Invalid("building the picker panicked".into())));
                let mut picker = match made {
                    Ok((picker, description)) => {
                        let _ = ready_tx.send(Ok(description));
                        picker
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                let mut batcher = Batcher {
                    receiver,
                    window,
                    max_rays: caps.0.max(1),
                    max_entries: caps.1.max(1),
                    stats: worker_stats,
                };
                batcher.run(picker.as_mut());
            })
            .map_err(|e| Error::Invalid(format!("could not start the picking thread: {e}")))?;
        let description = ready_rx
            .recv()
            .map_err(|_| Error::Invalid("the picking thread stopped while starting".into()))??;
        Ok(Worker {
            sender,
            stats,
            description,
        })
    }

    /// Queues a job; fails if the worker has stopped.
    pub(crate) fn submit(&self, job: Job) -> std::result::Result<(), String> {
        self.sender
            .send(job)
            .map_err(|_| "the picking worker has stopped".to_owned())
    }

    /// A snapshot of the counters.
    pub(crate) fn stats(&self) -> Stats {
        self.stats.lock().map(|s| *s).unwrap_or_default()
    }

    /// What answers picks ([`Picker::describe`]), e.g. `gpu llvmpipe (...) (Vulkan, Cpu)`.
    pub(crate) fn description(&self) -> &str {
        &self.description
    }
}

/// The picker for `backend`, with its one-line description ([`Picker::describe`]).
fn make_picker(backend: Backend, built: Arc<BuiltScene>) -> Result<(Box<dyn Picker>, String)> {
    let picker = crate::picker::make_picker(backend, built)?;
    let description = picker.describe();
    Ok((picker, description))
}

/// Prints the picker's fallback notes (the automatic backend's) on standard error.
fn show_notes(picker: &mut dyn Picker) {
    for note in picker.take_notes() {
        eprintln!("note: {note}");
    }
}

/// The worker's loop state.
struct Batcher {
    receiver: Receiver<Job>,
    window: Duration,
    /// A batch stops growing at this many rays...
    max_rays: usize,
    /// ...or this many all-hits list entries.
    max_entries: usize,
    stats: Arc<Mutex<Stats>>,
}

/// A pick job waiting in a batch.
struct PendingPick {
    rays: Vec<Ray>,
    reply: Reply<Answers>,
}

impl Batcher {
    /// Collects and answers batches until every sender is gone.
    fn run(&mut self, picker: &mut dyn Picker) {
        show_notes(picker);
        while let Ok(first) = self.receiver.recv() {
            let jobs = self.collect(first);
            self.answer(picker, jobs);
            show_notes(picker);
        }
    }

    /// `first` and whatever arrives within the batch window after it (or is already queued),
    /// up to the batch's caps.
    fn collect(&self, first: Job) -> Vec<Job> {
        let deadline = Instant::now() + self.window;
        let (mut rays, mut entries) = first.size();
        let mut jobs = vec![first];
        while rays < self.max_rays && entries < self.max_entries {
            let left = deadline.saturating_duration_since(Instant::now());
            let next = if left.is_zero() {
                match self.receiver.try_recv() {
                    Ok(job) => job,
                    Err(TryRecvError::Empty | TryRecvError::Disconnected) => break,
                }
            } else {
                match self.receiver.recv_timeout(left) {
                    Ok(job) => job,
                    Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => break,
                }
            };
            let (more_rays, more_entries) = next.size();
            rays = rays.saturating_add(more_rays);
            entries = entries.saturating_add(more_entries);
            jobs.push(next);
        }
        jobs
    }

    /// Answers one batch: one query call per distinct query, then the renders.
    fn answer(&self, picker: &mut dyn Picker, jobs: Vec<Job>) {
        let mut groups: Vec<(Query, Vec<PendingPick>)> = Vec::new();
        let mut renders = Vec::new();
        for job in jobs {
            match job {
                Job::Pick { rays, query, reply } => {
                    let key = group_key(query);
                    let pending = PendingPick { rays, reply };
                    match groups.iter_mut().find(|(q, _)| *q == key) {
                        Some((_, members)) => members.push(pending),
                        None => groups.push((key, vec![pending])),
                    }
                }
                Job::Render {
                    camera,
                    shade,
                    reply,
                } => renders.push((camera, shade, reply)),
            }
        }
        for (query, members) in groups {
            self.answer_group(picker, &query, members);
        }
        for (camera, shade, reply) in renders {
            let image = catch_unwind(AssertUnwindSafe(|| render(picker, &camera, shade)));
            let _ = reply.send(flatten(image, "rendering"));
            if let Ok(mut stats) = self.stats.lock() {
                stats.renders += 1;
            }
        }
    }

    /// One query call for every member of a group, split back to each member.
    fn answer_group(&self, picker: &mut dyn Picker, query: &Query, members: Vec<PendingPick>) {
        let count = members.len() as u64;
        let ray_total: usize = members.iter().map(|m| m.rays.len()).sum();
        if let Ok(mut stats) = self.stats.lock() {
            stats.pick_requests += count;
            stats.rays += ray_total as u64;
            stats.batches += 1;
            if count > 1 {
                stats.batched_requests += count;
            }
            stats.largest_batch = stats.largest_batch.max(count);
        }
        if let [single] = members.as_slice() {
            let answers = catch_unwind(AssertUnwindSafe(|| picker.query(&single.rays, query)));
            let answers = flatten(answers, "picking");
            let Some(member) = members.into_iter().next() else {
                return;
            };
            let _ = member.reply.send(answers);
            return;
        }
        let mut rays = Vec::with_capacity(ray_total);
        let mut ranges = Vec::with_capacity(members.len());
        for member in &members {
            let start = rays.len();
            rays.extend_from_slice(&member.rays);
            ranges.push(start..rays.len());
        }
        let answers = catch_unwind(AssertUnwindSafe(|| picker.query(&rays, query)));
        match flatten(answers, "picking") {
            Ok(answers) => {
                for (member, range) in members.into_iter().zip(ranges) {
                    let _ = member.reply.send(Ok(slice_answers(&answers, range)));
                }
            }
            Err(message) => {
                for member in members {
                    let _ = member.reply.send(Err(message.clone()));
                }
            }
        }
    }
}

/// The settings that decide which jobs may share a query call: `max_hits` matters only in
/// [`Mode::All`], so it is normalized away elsewhere.
fn group_key(query: Query) -> Query {
    if query.mode == Mode::All {
        query
    } else {
        Query {
            max_hits: Query::default().max_hits,
            ..query
        }
    }
}

/// A caught panic or an error as a sentence; the value otherwise.
fn flatten<T>(
    outcome: std::thread::Result<Result<T>>,
    what: &str,
) -> std::result::Result<T, String> {
    match outcome {
        Ok(Ok(value)) => Ok(value),
        Ok(Err(e)) => Err(format!("{what} failed: {e}")),
        Err(_) => Err(format!("{what} failed: the picker panicked")),
    }
}

/// The answers of rays `range`, renumbered from 0.
pub(crate) fn slice_answers(answers: &Answers, range: Range<usize>) -> Answers {
    let mut out = Answers {
        nearest: answers.nearest[range.clone()].to_vec(),
        ..Answers::default()
    };
    if !answers.list_start.is_empty() {
        let (from, to) = (
            answers.list_start[range.start],
            answers.list_start[range.end],
        );
        out.lists = answers.lists[from..to].to_vec();
        out.list_start = answers.list_start[range.start..=range.end]
            .iter()
            .map(|s| s - from)
            .collect();
        out.overflow = answers.overflow[range].to_vec();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::synthetic::{RayKind, example_scene, rays};
    use crate::{BuildOptions, Query};

    #[test]
    fn slices_match_subsets() {
        let built = Arc::new(BuiltScene::new(example_scene(), &BuildOptions::default()).unwrap());
        let rays = rays(&built.scene, RayKind::Camera, 64, 3);
        let mut picker = crate::picker::CpuPicker::new(built);
        for mode in [Mode::Closest, Mode::All] {
            let query = Query {
                mode,
                max_hits: 3,
                ..Query::default()
            };
            let answers = picker.query(&rays, &query).unwrap();
            for range in [0..0, 0..64, 5..17, 63..64] {
                let idx: Vec<usize> = range.clone().collect();
                assert_eq!(slice_answers(&answers, range), answers.subset(&idx));
            }
        }
    }
}
