//! The picking worker: one thread owns the picker (GPU or CPU) for the server's lifetime. Jobs
//! reach it over a channel; the pick jobs that arrive together (queued while it was busy, or
//! within the batch window after the first) are answered by ONE [`Picker::query`] call per
//! query settings, and the answers are split back to each job. The worker also renders views
//! and applies scene edits (add, move, re-mask, remove an object), since only it may touch the
//! picker, and keeps the [`Stats`] counters. Edits are applied between query calls, in the
//! order they arrived: every pick sees one version of the scene, and after each edit the worker
//! publishes the new version ([`SceneView`]) for `GET /scene`.

use super::frame_faults::{self, FrameFaults};
use super::steps::{Stepped, query_in_steps};
use crate::apps::camera::Camera;
use crate::apps::render::{Image, Shade, render_with};
use crate::error::{Error, Result};
use crate::picker::{Backend, BuiltScene, Picker};
use crate::query::{Answers, Mode, Query};
use crate::ray::Ray;
use crate::scene::{Mesh, box_of};
use glam::DVec3;
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
pub(crate) type Reply<T> = oneshot::Sender<std::result::Result<T, JobError>>;

/// Why a pick or a render failed, as a sentence.
#[derive(Clone, Debug)]
pub(crate) struct JobError {
    /// The work would have needed more than the process's memory budget
    /// ([`Error::OverBudget`]: 503); otherwise the picker failed (500).
    pub(crate) over_budget: bool,
    /// The work took longer than the server's work limit and was stopped (413).
    pub(crate) over_time: bool,
    /// What went wrong.
    pub(crate) message: String,
}

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
    /// Change the scene.
    Edit {
        /// What to change.
        edit: Edit,
        /// The object added or changed, or why not.
        reply: oneshot::Sender<std::result::Result<Edited, EditError>>,
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

/// What an edit did: the object added, changed or removed, and the warnings about where it
/// now lies ([`crate::frame::faults::placement_warnings`]: placements that are allowed and
/// still picked less exactly), each one sentence.
#[derive(Debug)]
pub(crate) struct Edited {
    /// The object's id.
    pub(crate) object: u32,
    /// The sentences; empty for most edits.
    pub(crate) warnings: Vec<String>,
}

/// A scene edit (`POST /objects`, `PATCH` and `DELETE /objects/{id}`).
pub(crate) enum Edit {
    /// Adds an object: a copy of an existing object's mesh as it was loaded, or a new mesh,
    /// placed by `transform` (file → world; none: as given) with layer mask `mask`.
    Add {
        /// Where the mesh comes from.
        mesh: MeshSource,
        /// 3 × 4 row-major affine transform, checked.
        transform: Option<[[f64; 4]; 3]>,
        /// Layer mask (default all bits).
        mask: Option<u32>,
    },
    /// Changes an object's transform (relative to the object as it was loaded or added) and/or
    /// mask.
    Change {
        /// The object.
        object: u32,
        /// The new transform, checked.
        transform: Option<[[f64; 4]; 3]>,
        /// The new mask.
        mask: Option<u32>,
    },
    /// Removes an object: it is never hit again, and `GET /scene` no longer lists it.
    Remove {
        /// The object.
        object: u32,
    },
}

/// Where an added object's mesh comes from.
pub(crate) enum MeshSource {
    /// The mesh of this existing object, as it was loaded or added.
    Copy(u32),
    /// A new mesh.
    Inline(Mesh),
}

/// The fewest triangles an added object counts as against
/// [`super::ServerConfig::max_added_triangles`]: each object's own entries (its name, its edit
/// state, its place in the tree and the views) weigh about as much as that many triangles, so
/// a client adding and removing tiny objects cannot grow them past what the cap allows.
pub(crate) const OBJECT_TRIANGLES: usize = 64;

/// Why an edit was refused: an unknown (or removed) object, or anything else wrong.
#[derive(Debug)]
pub(crate) enum EditError {
    /// No such object (404).
    NotFound(String),
    /// The scene would grow past its limit, or past what the GPU holds (413).
    TooLarge(String),
    /// The server failed to carry out a valid edit (500).
    Failed(String),
    /// A bad edit (400).
    Invalid(String),
    /// The edit would need more than the process's memory budget (503).
    OverBudget(String),
}

impl EditError {
    /// `e` as an edit error: [`EditError::OverBudget`] for [`Error::OverBudget`], else what
    /// `otherwise` makes of its sentence.
    fn of(e: Error, otherwise: fn(String) -> EditError) -> EditError {
        match e {
            Error::OverBudget(m) => EditError::OverBudget(m),
            e => otherwise(e.to_string()),
        }
    }
}

/// The scene as the picks see it, summarised for `GET /scene` and the answers' object names,
/// published by the worker after each edit. It holds no handle on the scene itself, so the
/// worker's picker is the scene's only owner and edits change it in place.
#[derive(Clone, Debug)]
pub(crate) struct SceneView {
    /// Per object, in id order.
    pub(crate) objects: Vec<ObjectView>,
    /// World bounds, when there are vertices.
    pub(crate) bounds: Option<(DVec3, DVec3)>,
    /// The tree's f64 origin.
    pub(crate) origin: DVec3,
    /// Triangles of the objects not removed.
    pub(crate) triangles: usize,
    /// Triangles the tree holds (removed objects' too, until a rebuild empties them): what
    /// its bytes are per.
    pub(crate) tree_triangles: usize,
    /// The tree: nodes, leaves, depth, GPU bytes.
    pub(crate) tree: (usize, usize, usize, u64),
}

/// One object of a [`SceneView`].
#[derive(Clone, Debug)]
pub(crate) struct ObjectView {
    pub(crate) id: u32,
    pub(crate) name: String,
    pub(crate) triangles: u32,
    pub(crate) mask: u32,
    pub(crate) grid: Option<crate::scene::GridShape>,
    /// The transform last set by an edit (none: as loaded).
    pub(crate) transform: Option<[[f64; 4]; 3]>,
    /// Removed by an edit.
    pub(crate) removed: bool,
}

impl SceneView {
    /// The view of `built`, with each object's edit state (transform, removed).
    pub(crate) fn of(built: &BuiltScene, edits: Vec<(Option<[[f64; 4]; 3]>, bool)>) -> Self {
        let bvh = &built.bvh;
        let tree = (
            bvh.nodes.len(),
            bvh.leaf_count(),
            bvh.depth(),
            bvh.gpu_bytes(),
        );
        if let Some(instances) = built.instances() {
            let objects: Vec<ObjectView> = instances
                .instances()
                .iter()
                .zip(edits.into_iter().chain(std::iter::repeat((None, false))))
                .enumerate()
                .map(|(k, (i, (transform, removed)))| {
                    let mesh = &instances.meshes()[i.mesh as usize].scene;
                    ObjectView {
                        id: k as u32,
                        name: i.name.clone(),
                        triangles: mesh.triangle_count() as u32,
                        mask: i.mask,
                        grid: mesh.objects()[0].grid,
                        transform,
                        removed,
                    }
                })
                .collect();
            return SceneView {
                triangles: live_triangles(&objects),
                tree_triangles: built.world_triangle_count() as usize,
                objects,
                bounds: built.bounds(),
                origin: bvh.origin,
                tree,
            };
        }
        let scene = &built.scene;
        let objects: Vec<ObjectView> = scene
            .objects()
            .iter()
            .zip(edits.into_iter().chain(std::iter::repeat((None, false))))
            .map(|(o, (transform, removed))| ObjectView {
                id: o.id,
                name: o.name.clone(),
                triangles: o.triangle_count,
                mask: o.mask,
                grid: o.grid,
                transform,
                removed,
            })
            .collect();
        // With every object removed nothing can be hit: no bounds, as an instanced scene's
        // (the tree keeps the last one's triangles, masked, until an edit builds it again, and
        // its bounds framed the removed object in `GET /scene` and the viewer's first view).
        let bounds = match objects.iter().all(|o| o.removed) {
            true => None,
            false => scene.bounds(),
        };
        SceneView {
            triangles: live_triangles(&objects),
            tree_triangles: scene.triangle_count(),
            objects,
            bounds,
            origin: bvh.origin,
            tree,
        }
    }
}

/// The triangles of the objects not removed.
fn live_triangles(objects: &[ObjectView]) -> usize {
    objects
        .iter()
        .filter(|o| !o.removed)
        .map(|o| o.triangles as usize)
        .sum()
}

/// `scene` with every removed object emptied (`objects`: each object's edit state), for a
/// rebuild: what they held given back, their ids kept ([`crate::scene::Scene::with_objects_emptied`]).
fn without_removed(
    scene: &crate::scene::Scene,
    objects: &[(Option<[[f64; 4]; 3]>, bool)],
) -> crate::scene::Scene {
    scene.with_objects_emptied(|k| objects.get(k as usize).is_some_and(|o| o.1))
}

/// Whether `object` exists and was not removed (`objects`: each object's edit state), else a
/// 404 naming it.
fn live(
    objects: &[(Option<[[f64; 4]; 3]>, bool)],
    object: u32,
) -> std::result::Result<(), EditError> {
    objects
        .get(object as usize)
        .is_some_and(|&(_, removed)| !removed)
        .then_some(())
        .ok_or_else(|| EditError::NotFound(format!("there is no object {object}")))
}

/// `a ∘ b`: the affine map applying `b`, then `a` (3 × 4 row-major), in f64.
fn compose(a: &[[f64; 4]; 3], b: &[[f64; 4]; 3]) -> [[f64; 4]; 3] {
    let mut out = [[0.0; 4]; 3];
    for r in 0..3 {
        for c in 0..4 {
            out[r][c] = a[r][0] * b[0][c] + a[r][1] * b[1][c] + a[r][2] * b[2][c];
        }
        out[r][3] += a[r][3];
    }
    out
}

/// Whether `transform` mirrors (a negative determinant); none does not.
fn mirrors(transform: &Option<[[f64; 4]; 3]>) -> bool {
    transform.is_some_and(|t| crate::scene::check_transform(&t).is_ok_and(|d| d < 0.0))
}

/// The published [`SceneView`], shared with the request handlers.
pub(crate) type SharedView = Arc<Mutex<Arc<SceneView>>>;

impl Job {
    /// Rays this job traces and all-hits list entries it keeps (for the batch size caps).
    fn size(&self) -> (usize, usize) {
        match self {
            Job::Edit { .. } => (0, 0),
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
        view: SharedView,
        max_added_triangles: usize,
        max_work: Duration,
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
                let objects = view.lock().map_or(0, |v| v.objects.len());
                let mut batcher = Batcher {
                    receiver,
                    window,
                    max_rays: caps.0.max(1),
                    max_entries: caps.1.max(1),
                    stats: worker_stats,
                    backend,
                    view,
                    loaded: vec![None; objects],
                    placed: vec![None; objects],
                    faults: None,
                    added_triangles: 0,
                    counted: vec![0; objects],
                    max_added_triangles,
                    max_work,
                    notes_shown: Default::default(),
                };
                batcher.run(&mut picker);
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

/// Object `object`'s triangles as stored (a mirrored object's with the winding that keeps its
/// front faces front), with vertex indices into its own vertices.
fn object_triangles(scene: &crate::scene::Scene, object: u32) -> Vec<[u32; 3]> {
    let o = &scene.objects()[object as usize];
    (o.first_triangle..o.first_triangle + o.triangle_count)
        .map(|t| {
            scene
                .triangle_vertices(t as usize)
                .map(|v| v - o.first_vertex)
        })
        .collect()
}

/// The picker for `backend`, with its one-line description ([`Picker::describe`]).
fn make_picker(backend: Backend, built: Arc<BuiltScene>) -> Result<(Box<dyn Picker>, String)> {
    let picker = crate::picker::make_picker(backend, built)?;
    let description = picker.describe();
    Ok((picker, description))
}

/// The picker for `backend` over `built` (a scene built anew), made from `old`'s device and
/// compiled kernel where it has them ([`Picker::remake`]): a server's rebuilding edits opened a
/// device and compiled the kernel each time. Where that fails for another reason than the
/// scene's size (a lost device), one is made afresh.
fn remade(old: &dyn Picker, backend: Backend, built: Arc<BuiltScene>) -> Result<Box<dyn Picker>> {
    match old.remake(built.clone()) {
        Some(Ok(picker)) => Ok(picker),
        Some(Err(e @ Error::TooLargeForGpu { .. })) => Err(e),
        Some(Err(_)) | None => make_picker(backend, built).map(|(picker, _)| picker),
    }
}

/// Prints the picker's notes (the automatic backend's fallbacks, a GPU device lost and opened
/// again) on standard error, each once over the server's life: a picker made again over an
/// edited scene says them again (every `POST /objects` printed "no GPU …" anew). Each loss of
/// the device is said: its note names the opening.
fn show_notes(picker: &mut dyn Picker, shown: &mut std::collections::HashSet<String>) {
    for note in picker.take_notes() {
        if shown.insert(note.clone()) {
            // Lost, not a panic, where standard error is closed.
            use std::io::Write as _;
            let _ = writeln!(std::io::stderr(), "note: {note}");
        }
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
    /// The backend, for a picker over a rebuilt scene.
    backend: Backend,
    /// The scene version last published.
    view: SharedView,
    /// Per object: its positions as loaded or added, kept from its first move on.
    loaded: Vec<Option<Vec<DVec3>>>,
    /// Per instance of an instanced scene: its transform as loaded or added, kept from its
    /// first move on.
    placed: Vec<Option<[[f64; 4]; 3]>>,
    /// What a plain scene's frame fails to hold, when counted since the last edit that may
    /// have changed it.
    faults: Option<FrameFaults>,
    /// An instanced scene's triangles added by edits so far, as counted against the cap
    /// ([`Batcher::counted_with`]: its meshes are stored for good)...
    added_triangles: usize,
    /// ...a plain scene's, per object: what it counts while not removed (0 for those loaded);
    /// once removed, its triangles are given back at the next addition's rebuild, and it
    /// counts as [`OBJECT_TRIANGLES`] from there on ([`Batcher::plain_added`])...
    counted: Vec<usize>,
    /// ...and at most.
    max_added_triangles: usize,
    /// The longest one query call's steps may run ([`super::ServerConfig::max_work`]).
    max_work: Duration,
    /// The pickers' notes printed so far ([`show_notes`]).
    notes_shown: std::collections::HashSet<String>,
}

/// A pick job waiting in a batch.
struct PendingPick {
    rays: Vec<Ray>,
    reply: Reply<Answers>,
}

impl Batcher {
    /// Collects and answers batches until every sender is gone.
    fn run(&mut self, picker: &mut Box<dyn Picker>) {
        show_notes(picker.as_mut(), &mut self.notes_shown);
        while let Ok(first) = self.receiver.recv() {
            let jobs = self.collect(first);
            // Picks and renders up to each edit, then the edit: no query call straddles one.
            let mut part = Vec::new();
            for job in jobs {
                match job {
                    Job::Edit { edit, reply } => {
                        self.answer(picker.as_mut(), std::mem::take(&mut part));
                        // What the picks so far had to say: the edit may replace the picker.
                        show_notes(picker.as_mut(), &mut self.notes_shown);
                        let removal = matches!(edit, Edit::Remove { .. });
                        let done = catch_unwind(AssertUnwindSafe(|| self.apply(picker, edit)))
                            .unwrap_or_else(|_| Err(EditError::Failed("the edit panicked".into())))
                            .map(|object| Edited {
                                object,
                                warnings: match (removal, picker.current_scene()) {
                                    (false, Some(built)) => {
                                        crate::frame::faults::placement_warnings(&built, object)
                                    }
                                    _ => Vec::new(),
                                },
                            })
                            .map_err(|e| self.without_paths(e));
                        let _ = reply.send(done);
                    }
                    job => part.push(job),
                }
            }
            self.answer(picker.as_mut(), part);
            show_notes(picker.as_mut(), &mut self.notes_shown);
        }
    }

    /// `e` with each object's name as answers show it (`api::public_name`: the file name
    /// without its folders), so a refused edit never shows the server's paths: the library's
    /// sentences name an instance by its file's path ("instance 1 (\"/srv/scenes/tower.obj\")").
    fn without_paths(&self, e: EditError) -> EditError {
        let Ok(view) = self.view.lock().map(|v| v.clone()) else {
            return e;
        };
        // Each name as sentences write it, and as shown: quoted after its id (`instance 3
        // ("…")`: cut to 60 characters and escaped by `budget::quote`, so long paths that differ
        // only past their folders are told apart by the id), and whole.
        let mut by_id: Vec<(String, String)> = Vec::new();
        let mut names: Vec<(String, String)> = Vec::new();
        for o in &view.objects {
            let shown = super::api::public_name(&o.name);
            if shown.len() < o.name.len() {
                let (quoted, quoted_shown) =
                    (crate::budget::quote(&o.name), crate::budget::quote(shown));
                for kind in ["instance", "object"] {
                    by_id.push((
                        format!("{kind} {} (\"{quoted}\")", o.id),
                        format!("{kind} {} (\"{quoted_shown}\")", o.id),
                    ));
                }
                names.push((o.name.clone(), shown.to_owned()));
            }
        }
        // Longer names first: one may hold another ("a/b.obj" in "x/a/b.obj").
        names.sort_unstable_by_key(|(written, _)| std::cmp::Reverse(written.len()));
        names.dedup();
        by_id.append(&mut names);
        let names = by_id;
        let public = |mut sentence: String| {
            for (written, shown) in &names {
                if sentence.contains(written.as_str()) {
                    sentence = sentence.replace(written.as_str(), shown);
                }
            }
            sentence
        };
        match e {
            EditError::NotFound(m) => EditError::NotFound(public(m)),
            EditError::TooLarge(m) => EditError::TooLarge(public(m)),
            EditError::Failed(m) => EditError::Failed(public(m)),
            EditError::Invalid(m) => EditError::Invalid(public(m)),
            EditError::OverBudget(m) => EditError::OverBudget(public(m)),
        }
    }

    /// Applies `edit` to the picker's scene and publishes the new version. The picker's scene
    /// is shared with no one while it changes (the published view holds a summary, not the
    /// scene, and this function lets go of its own handle first), so a move refits in place
    /// instead of copying the scene.
    fn apply(
        &mut self,
        picker: &mut Box<dyn Picker>,
        edit: Edit,
    ) -> std::result::Result<u32, EditError> {
        let invalid = |e: Error| EditError::of(e, EditError::Invalid);
        let view = self
            .view
            .lock()
            .map(|v| v.clone())
            .map_err(|_| EditError::Failed("the scene view is unavailable".into()))?;
        let mut objects: Vec<(Option<[[f64; 4]; 3]>, bool)> = view
            .objects
            .iter()
            .map(|o| (o.transform, o.removed))
            .collect();
        drop(view);
        let scene_of = |picker: &dyn Picker| {
            picker
                .current_scene()
                .ok_or_else(|| EditError::Failed("this picker cannot change its scene".into()))
        };
        if scene_of(picker.as_ref())?.instances().is_some() {
            let object = self.apply_instanced(picker, edit, &mut objects)?;
            return self.publish(picker.as_ref(), objects, object);
        }
        // What the scene's frame fails to hold now (nothing, but for a scene loaded so): an
        // edit after which it fails more is refused.
        let before = match self.faults {
            Some(f) => f,
            None => FrameFaults::of(&*scene_of(picker.as_ref())?),
        };
        let object = match edit {
            Edit::Change {
                object,
                transform,
                mask,
            } => {
                live(&objects, object)?;
                if let Some(transform) = transform {
                    let built = scene_of(picker.as_ref())?;
                    let loaded = self.loaded_positions(&built, object);
                    let current = objects[object as usize].0;
                    // Where the vertices are now: the loaded ones through the transform last
                    // set, as that move placed them (bit for bit).
                    let placed = |t: &Option<[[f64; 4]; 3]>| -> Vec<DVec3> {
                        match t {
                            Some(t) => loaded
                                .iter()
                                .map(|&p| crate::scene::apply_transform(t, p))
                                .collect(),
                            None => loaded.clone(),
                        }
                    };
                    let (now_at, moved) = (placed(&current), placed(&Some(transform)));
                    frame_faults::refuse_collapse(
                        object,
                        &object_triangles(&built.scene, object),
                        &now_at,
                        &moved,
                    )?;
                    if mirrors(&Some(transform)) == mirrors(&current) {
                        // The same handedness: the vertices move, the tree is refitted.
                        let frame = built.bvh.origin;
                        drop(built);
                        let here = box_of(now_at.iter().copied());
                        let refit = picker.set_positions(object, &moved).map_err(invalid)?;
                        // A refit keeps the frame and every triangle it held, so only the moved
                        // object can leave its reach; a rebuild re-centres the frame, which may
                        // leave any object far from the new centre.
                        let now = scene_of(picker.as_ref())?;
                        let refused = if refit == crate::picker::Refit::Rebuilt {
                            before.after(&now, Some(object))
                        } else {
                            let there = box_of(moved.iter().copied());
                            match frame_faults::moved(object, here, there, &now, before) {
                                Ok(after) => (after, None),
                                Err(refused) => (before, Some(refused)),
                            }
                        };
                        drop(now);
                        match refused {
                            (after, None) => self.faults = Some(after),
                            (_, Some(refused)) => {
                                self.move_back(picker, object, &now_at, frame)?;
                                return Err(refused);
                            }
                        }
                    } else {
                        // A mirror comes or goes: the winding flips, so the tree is built anew.
                        // Built without what removed objects held, as an addition's.
                        let mut scene = without_removed(&built.scene, &objects);
                        let options = *built.options();
                        drop(built);
                        scene
                            .set_object_positions(object, &loaded)
                            .map_err(invalid)?;
                        if mirrors(&current) {
                            // Back to the loaded winding first.
                            scene.flip_winding(object);
                        }
                        scene
                            .transform_object(object, &transform)
                            .map_err(invalid)?;
                        self.rebuild(picker, scene, &options, before, Some(object))?;
                    }
                    objects[object as usize].0 = Some(transform);
                }
                if let Some(mask) = mask {
                    picker.set_mask(object, mask).map_err(invalid)?;
                }
                object
            }
            Edit::Remove { object } => {
                live(&objects, object)?;
                picker.set_mask(object, 0).map_err(invalid)?;
                objects[object as usize].1 = true;
                if let Some(loaded) = self.loaded.get_mut(object as usize) {
                    *loaded = None;
                }
                self.gather_removed(picker, object, &objects, before);
                object
            }
            Edit::Add {
                mesh,
                transform,
                mask,
            } => {
                let built = scene_of(picker.as_ref())?;
                // The copy of an object as it was loaded or added: its positions then, its
                // triangles in file order, and whether it was mirrored then.
                let (mesh, mirrored) = match mesh {
                    MeshSource::Copy(source) => {
                        live(&objects, source)?;
                        let stored = built.scene.objects()[source as usize].mirrored;
                        let mut triangles = object_triangles(&built.scene, source);
                        if stored {
                            triangles.iter_mut().for_each(|t| t.swap(1, 2));
                        }
                        let positions = self.loaded_positions(&built, source);
                        let loaded_mirrored = stored != mirrors(&objects[source as usize].0);
                        (
                            Mesh {
                                positions,
                                triangles,
                            },
                            loaded_mirrored,
                        )
                    }
                    MeshSource::Inline(mesh) => (mesh, false),
                };
                // The scene is rebuilt without what removed objects held (their ids kept), so
                // adding and removing objects does not grow it.
                let triangles = mesh.triangles.len();
                let held = self.plain_added(&objects);
                self.counted_with(held, &format!("{triangles} triangles"), triangles)?;
                let mut scene = without_removed(&built.scene, &objects);
                let mut options = *built.options();
                drop(built);
                let id = scene
                    .add_mesh(format!("object {}", objects.len()), mesh)
                    .map_err(invalid)?;
                if mirrored {
                    scene.flip_winding(id);
                }
                let before_transform: Option<Vec<DVec3>> = transform.map(|_| {
                    scene
                        .object_vertices(id)
                        .map(|v| scene.position(v))
                        .collect()
                });
                if let (Some(transform), Some(before)) = (&transform, &before_transform) {
                    scene.transform_object(id, transform).map_err(invalid)?;
                    let after: Vec<DVec3> = scene
                        .object_vertices(id)
                        .map(|v| scene.position(v))
                        .collect();
                    frame_faults::refuse_collapse(
                        id,
                        &object_triangles(&scene, id),
                        before,
                        &after,
                    )?;
                }
                if let Some(mask) = mask {
                    scene.set_object_mask(id, mask).map_err(invalid)?;
                }
                // The grid builder takes one height grid; with an object added, median cut.
                if options.builder == crate::bvh::Builder::Grid {
                    options.builder = crate::bvh::Builder::Auto;
                }
                self.rebuild(picker, scene, &options, before, Some(id))?;
                // Only now that the object exists: its positions before its transform.
                if self.loaded.len() <= id as usize {
                    self.loaded.resize(id as usize + 1, None);
                }
                self.loaded[id as usize] = before_transform;
                if self.counted.len() <= id as usize {
                    self.counted.resize(id as usize + 1, 0);
                }
                self.counted[id as usize] = triangles.max(OBJECT_TRIANGLES);
                objects.push((transform, false));
                id
            }
        };
        self.publish(picker.as_ref(), objects, object)
    }

    /// A plain scene's triangles added so far as the cap counts them (`objects`: each object's
    /// edit state): each removed object as its entries, not its triangles, which the rebuild
    /// of the addition being counted gives back.
    fn plain_added(&self, objects: &[(Option<[[f64; 4]; 3]>, bool)]) -> usize {
        self.counted
            .iter()
            .zip(objects)
            .map(|(&c, &(_, removed))| if removed { c.min(OBJECT_TRIANGLES) } else { c })
            .sum()
    }

    /// The triangles added to this server, `held` so far, with `what` more, which stores
    /// `triangles` (none for an instance of a stored mesh), each object counted as at least
    /// [`OBJECT_TRIANGLES`]; 413 past the server's limit.
    fn counted_with(
        &self,
        held: usize,
        what: &str,
        triangles: usize,
    ) -> std::result::Result<usize, EditError> {
        let counted = triangles.max(OBJECT_TRIANGLES);
        let total = held.saturating_add(counted);
        if total > self.max_added_triangles {
            let as_counted = if counted > triangles {
                format!(
                    " (counted as {counted}: each object counts as at least {OBJECT_TRIANGLES})"
                )
            } else {
                String::new()
            };
            return Err(EditError::TooLarge(format!(
                "adding {what}{as_counted} would bring the triangles added to this server to \
                 {total}, over its limit of {}",
                self.max_added_triangles
            )));
        }
        Ok(total)
    }

    /// Publishes the scene's new version (`objects`: each object's edit state) and answers
    /// `object`.
    fn publish(
        &self,
        picker: &dyn Picker,
        objects: Vec<(Option<[[f64; 4]; 3]>, bool)>,
        object: u32,
    ) -> std::result::Result<u32, EditError> {
        let built = picker
            .current_scene()
            .ok_or_else(|| EditError::Failed("this picker cannot change its scene".into()))?;
        let published = Arc::new(SceneView::of(&built, objects));
        drop(built);
        if let Ok(mut view) = self.view.lock() {
            *view = published;
        }
        Ok(object)
    }

    /// [`Batcher::apply`] on an instanced scene: a move sets the instance's transform (the
    /// edit's composed with the one it was loaded or added with) and refits the top tree; a
    /// mask or a removal sets its mask; a copy adds an instance of the source's mesh, stored
    /// once; an inline mesh is added as a mesh and placed once.
    fn apply_instanced(
        &mut self,
        picker: &mut Box<dyn Picker>,
        edit: Edit,
        objects: &mut Vec<(Option<[[f64; 4]; 3]>, bool)>,
    ) -> std::result::Result<u32, EditError> {
        let invalid = |e: Error| EditError::of(e, EditError::Invalid);
        let failed = |e: Error| match e {
            Error::TooLargeForGpu { .. } => EditError::TooLarge(e.to_string()),
            e => EditError::of(e, EditError::Failed),
        };
        Ok(match edit {
            Edit::Change {
                object,
                transform,
                mask,
            } => {
                live(objects, object)?;
                if let Some(transform) = transform {
                    let world =
                        compose(&transform, &self.placed_transform(picker.as_ref(), object)?);
                    picker
                        .edit(&mut |b| b.set_instance_transform(object, world))
                        .map_err(invalid)?;
                    objects[object as usize].0 = Some(transform);
                }
                if let Some(mask) = mask {
                    picker
                        .edit(&mut |b| b.set_instance_mask(object, mask))
                        .map_err(invalid)?;
                }
                object
            }
            Edit::Remove { object } => {
                live(objects, object)?;
                let bounds = |p: &dyn Picker| p.current_scene().and_then(|b| b.bounds());
                let before = bounds(picker.as_ref());
                picker
                    .edit(&mut |b| b.remove_instance(object))
                    .map_err(invalid)?;
                objects[object as usize].1 = true;
                // An instance that reached the bounds' edge drew the frame's centre towards it:
                // the top tree is laid out again, re-centred where that resolves the rest as
                // finely (a huge instance added and removed left the others in a frame centred
                // far away, picked more coarsely, until the next addition).
                if bounds(picker.as_ref()) != before {
                    picker.edit(&mut |b| b.rebuild_top()).map_err(failed)?;
                }
                object
            }
            Edit::Add {
                mesh,
                transform,
                mask,
            } => {
                if let Some(t) = &transform {
                    crate::scene::check_transform(t)
                        .map_err(|why| EditError::Invalid(format!("the transform {why}")))?;
                }
                let built = picker.current_scene().ok_or_else(|| {
                    EditError::Failed("this picker cannot change its scene".into())
                })?;
                let instances = built.instances().expect("an instanced scene");
                // An instance of a stored mesh stores no triangles: it counts as its entries.
                let (source, base, triangles) = match &mesh {
                    MeshSource::Copy(source) => {
                        live(objects, *source)?;
                        (Some(instances.instances()[*source as usize].mesh), None, 0)
                    }
                    MeshSource::Inline(m) => {
                        (None, Some(crate::instance::IDENTITY), m.triangles.len())
                    }
                };
                drop(built);
                let what = match source {
                    Some(_) => "an instance".to_owned(),
                    None => format!("{triangles} triangles"),
                };
                let total = self.counted_with(self.added_triangles, &what, triangles)?;
                let base = match (&mesh, base) {
                    (MeshSource::Copy(source), _) => {
                        self.placed_transform(picker.as_ref(), *source)?
                    }
                    (_, base) => base.unwrap_or(crate::instance::IDENTITY),
                };
                let name = format!("object {}", objects.len());
                let mesh_index = match (source, mesh) {
                    (Some(m), _) => m,
                    (None, MeshSource::Inline(m)) => {
                        let mut one = crate::scene::Scene::new();
                        one.add_mesh(name.clone(), m).map_err(invalid)?;
                        let mut added = 0;
                        picker
                            .edit(&mut |b| {
                                added = b.add_mesh(one.clone())?;
                                Ok(crate::picker::Refit::Moved)
                            })
                            .map_err(|e| match e {
                                Error::Invalid(_) => invalid(e),
                                e => failed(e),
                            })?;
                        // The mesh is stored from here on, placed or not: counted now, so
                        // refused placements cannot add meshes past the cap.
                        self.added_triangles = total;
                        added
                    }
                    (None, MeshSource::Copy(_)) => unreachable!("a copy has its source's mesh"),
                };
                let instance = crate::instance::Instance {
                    name,
                    mesh: mesh_index,
                    transform: transform.map_or(base, |t| compose(&t, &base)),
                    mask: mask.unwrap_or(u32::MAX),
                };
                let mut id = 0;
                picker
                    .edit(&mut |b| {
                        id = b.add_instance(instance.clone())?;
                        Ok(crate::picker::Refit::Rebuilt)
                    })
                    .map_err(|e| match e {
                        Error::Invalid(_) => invalid(e),
                        e => failed(e),
                    })?;
                if self.placed.len() <= id as usize {
                    self.placed.resize(id as usize + 1, None);
                }
                self.placed[id as usize] = Some(base);
                self.added_triangles = total;
                objects.push((transform, false));
                id
            }
        })
    }

    /// Instance `object`'s transform as it was loaded or added (kept from its first move on).
    fn placed_transform(
        &mut self,
        picker: &dyn Picker,
        object: u32,
    ) -> std::result::Result<[[f64; 4]; 3], EditError> {
        if self.placed.len() <= object as usize {
            self.placed.resize(object as usize + 1, None);
        }
        if let Some(t) = self.placed[object as usize] {
            return Ok(t);
        }
        let built = picker
            .current_scene()
            .ok_or_else(|| EditError::Failed("this picker cannot change its scene".into()))?;
        let t = built
            .instances()
            .and_then(|i| i.instances().get(object as usize))
            .map(|i| i.transform)
            .ok_or_else(|| EditError::NotFound(format!("there is no object {object}")))?;
        self.placed[object as usize] = Some(t);
        Ok(t)
    }

    /// Undoes a refused move of `object`: its vertices back `here`, in the frame centred on
    /// `frame` as before. Moving back refits in the frame the refused move made, so where that
    /// move re-centred it (a rebuild: it widened the scene), the scene is built again, centred
    /// on its bounds as a fresh build is.
    fn move_back(
        &mut self,
        picker: &mut Box<dyn Picker>,
        object: u32,
        here: &[DVec3],
        frame: DVec3,
    ) -> std::result::Result<(), EditError> {
        let failed = |e: Error| match e {
            Error::OverBudget(m) => {
                EditError::OverBudget(format!("the move could not be undone: {m}"))
            }
            e => EditError::Failed(format!("the move could not be undone: {e}")),
        };
        picker.set_positions(object, here).map_err(failed)?;
        let built = picker
            .current_scene()
            .ok_or_else(|| EditError::Failed("this picker cannot change its scene".into()))?;
        if built.bvh.origin == frame {
            return Ok(());
        }
        let (scene, options) = (built.scene.clone(), *built.options());
        drop(built);
        let rebuilt = BuiltScene::new(scene, &options).map_err(failed)?;
        *picker = remade(picker.as_ref(), self.backend, Arc::new(rebuilt)).map_err(failed)?;
        self.faults = None;
        Ok(())
    }

    /// After `object` was removed (its mask 0): where it reached the edge of the scene's
    /// bounds, the scene is built again with every removed object emptied (no triangles, no
    /// vertices: `Scene::with_objects_emptied`), so its bounds, its framing camera and its
    /// frame's centre are those of what is left. Without it, one far object added and removed
    /// kept them wide for every client: the first view empty, and nearby additions refused as
    /// too far from the centre. Where the rebuild cannot be made, the removal stands as a mask.
    /// (A removed object inside the bounds is left where it is until the next addition, or a
    /// removal that empties them all: should moves of the others shrink the bounds, they may
    /// then reach it until then.)
    fn gather_removed(
        &mut self,
        picker: &mut Box<dyn Picker>,
        object: u32,
        objects: &[(Option<[[f64; 4]; 3]>, bool)],
        before: FrameFaults,
    ) {
        let Some(built) = picker.current_scene() else {
            return;
        };
        let scene = &built.scene;
        let (Some((lo, hi)), Some(removed)) =
            (scene.bounds(), scene.objects().get(object as usize))
        else {
            return;
        };
        let points = |k: u32| scene.object_vertices(k).map(|v| scene.position(v));
        let (rlo, rhi) = box_of(points(object));
        if removed.triangle_count == 0 || (rlo.cmpgt(lo).all() && rhi.cmplt(hi).all()) {
            // Inside the bounds on every side: they stay as they are.
            return;
        }
        let left = box_of(
            (0..scene.objects().len() as u32)
                .filter(|&k| !objects.get(k as usize).is_some_and(|o| o.1))
                .flat_map(points),
        );
        if !left.0.is_finite() || left == (lo, hi) {
            return;
        }
        // Every removed object is emptied (one removed earlier, inside bounds that this one
        // held wide, would reach past what is left once they shrink).
        let emptied = without_removed(scene, objects);
        let options = *built.options();
        drop(built);
        // A smaller frame resolves what is left at least as finely; a refusal or a failure
        // leaves the masked scene serving.
        let _ = self.rebuild(picker, emptied, &options, before, None);
    }

    /// Builds `scene` with `options` and puts a new picker over it in `picker`'s place; refused,
    /// with nothing changed, when its frame fails to hold more than `before` (the scene's
    /// before the edit of object `edited`: [`FrameFaults::after`]).
    fn rebuild(
        &mut self,
        picker: &mut Box<dyn Picker>,
        scene: crate::scene::Scene,
        options: &crate::bvh::BuildOptions,
        before: FrameFaults,
        edited: Option<u32>,
    ) -> std::result::Result<(), EditError> {
        let failed = |e: Error| match e {
            Error::TooLargeForGpu { .. } => EditError::TooLarge(e.to_string()),
            e => EditError::of(e, EditError::Failed),
        };
        let rebuilt = BuiltScene::new(scene, options).map_err(failed)?;
        let (after, refused) = before.after(&rebuilt, edited);
        if let Some(refused) = refused {
            return Err(refused);
        }
        *picker = remade(picker.as_ref(), self.backend, Arc::new(rebuilt)).map_err(failed)?;
        self.faults = Some(after);
        Ok(())
    }

    /// Object `object`'s positions as it was loaded or added (kept from its first move on).
    fn loaded_positions(&mut self, built: &BuiltScene, object: u32) -> Vec<DVec3> {
        if self.loaded.len() <= object as usize {
            self.loaded.resize(object as usize + 1, None);
        }
        self.loaded[object as usize]
            .get_or_insert_with(|| {
                built
                    .scene
                    .object_vertices(object)
                    .map(|v| built.scene.position(v))
                    .collect()
            })
            .clone()
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
                Job::Edit { reply, .. } => {
                    // `run` applies edits itself, between the batches it answers here.
                    let _ = reply.send(Err(EditError::Invalid("an edit reached a batch".into())));
                }
                // A client gone while its job waited (its handler dropped with its
                // connection): nothing to answer.
                Job::Pick { reply, .. } if reply.is_closed() => {}
                Job::Render { reply, .. } if reply.is_closed() => {}
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
            // In steps too, stopped when the client is gone or past the work limit.
            let image = catch_unwind(AssertUnwindSafe(|| {
                render_with(&camera, shade, |rays| {
                    let stepped = query_in_steps(
                        picker,
                        rays,
                        &Query::default(),
                        || !reply.is_closed(),
                        self.max_work,
                    )?;
                    Ok(match stepped {
                        Stepped::Done(answers) => Ok(answers.nearest),
                        Stepped::Unwanted => Err(None),
                        Stepped::OverTime { answered } => Err(Some(answered.nearest.len())),
                    })
                })
            }));
            let image = match flatten(image, "rendering") {
                Ok(Err(None)) => continue,
                Ok(Err(Some(answered))) => Err(self.over_time(
                    "this render",
                    answered,
                    camera.width() as usize * camera.height() as usize,
                    "pixels",
                )),
                Ok(Ok(image)) => Ok(image),
                Err(error) => Err(error),
            };
            let _ = reply.send(image);
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
        // In steps, until no member waits any longer, or past the work limit (`steps`). The
        // limit is each request's: when the steps stop inside one member's rays, that member
        // gets 413, those before it their answers, and those after it start again with a clock
        // of their own (a request batched behind a costly one is not refused for its time).
        let mut members = members;
        while !members.is_empty() {
            members = self.answer_members(picker, query, members);
        }
    }

    /// One stepped query call over `members`' rays: answers (or refuses) the members it
    /// reached and returns those it did not start before the work limit stopped it.
    fn answer_members(
        &self,
        picker: &mut dyn Picker,
        query: &Query,
        members: Vec<PendingPick>,
    ) -> Vec<PendingPick> {
        let ray_total: usize = members.iter().map(|m| m.rays.len()).sum();
        let wanted = || members.iter().any(|m| !m.reply.is_closed());
        let mut rays;
        let all: &[Ray] = if let [single] = members.as_slice() {
            &single.rays
        } else {
            rays = Vec::with_capacity(ray_total);
            for member in &members {
                rays.extend_from_slice(&member.rays);
            }
            &rays
        };
        let answers = catch_unwind(AssertUnwindSafe(|| {
            query_in_steps(picker, all, query, wanted, self.max_work)
        }));
        let (answers, answered) = match flatten(answers, "picking") {
            Ok(Stepped::Unwanted) => return Vec::new(),
            Ok(Stepped::Done(answers)) => (answers, ray_total),
            Ok(Stepped::OverTime { answered }) => {
                let n = answered.nearest.len();
                (answered, n)
            }
            Err(error) => {
                for member in members {
                    let _ = member.reply.send(Err(error.clone()));
                }
                return Vec::new();
            }
        };
        if members.len() == 1 && answered == ray_total {
            if let Some(member) = members.into_iter().next() {
                let _ = member.reply.send(Ok(answers));
            }
            return Vec::new();
        }
        let mut start = 0;
        let mut not_started = Vec::new();
        for member in members {
            let range = start..start + member.rays.len();
            start = range.end;
            if range.end <= answered {
                let _ = member.reply.send(Ok(slice_answers(&answers, range)));
            } else if range.start >= answered {
                not_started.push(member);
            } else {
                let own = answered - range.start;
                let refused = self.over_time("this pick", own, range.len(), "rays");
                let _ = member.reply.send(Err(refused));
            }
        }
        not_started
    }

    /// The error of work stopped at the work limit after `answered` of `total` `items`.
    fn over_time(&self, what: &str, answered: usize, total: usize, items: &str) -> JobError {
        JobError {
            over_budget: false,
            over_time: true,
            message: format!(
                "{what} was stopped after {answered} of its {total} {items}: it passed this \
                 server's work limit of {} s for one request (--max-work-seconds); send fewer \
                 {items} at a time",
                crate::io::output::csv_number(self.max_work.as_secs_f64())
            ),
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
) -> std::result::Result<T, JobError> {
    match outcome {
        Ok(Ok(value)) => Ok(value),
        Ok(Err(e)) => Err(JobError {
            over_budget: matches!(e, Error::OverBudget(_)),
            over_time: false,
            message: format!("{what} failed: {e}"),
        }),
        Err(_) => Err(JobError {
            over_budget: false,
            over_time: false,
            message: format!("{what} failed: the picker panicked"),
        }),
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
