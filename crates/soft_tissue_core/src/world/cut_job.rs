//! A cut in two halves: [`WorldBody::begin_cut`] takes what the cut needs of the body (its
//! rest mesh, its shape now, its settings, heat and cut history) and prepares the cut mesh
//! and the bodies of its pieces, in the step or on a thread of its own; [`WorldBody::finish_cut`]
//! lands it, handing the body's state at that step to the pieces. Preparing is a pure
//! function of what was taken, so a cut lands the same whenever its thread ran.

use super::cut::{
    CutRecord, carried_boundary, carried_heat_boundary, fixed_axes, held_axes, lumped_volumes,
    single_node, supports, surface_closed,
};
use super::*;
use crate::mesh::cut::{Ball, CutHistory, CutOptions, CutTriangle, NodeOrigin, recut_within};
use crate::mesh::pieces::pieces;
use std::sync::atomic::{AtomicBool, Ordering};

/// A cut begun by [`WorldBody::begin_cut`], to land with [`WorldBody::finish_cut`].
#[derive(Debug)]
pub struct CutJob {
    /// The body's rest mesh and settings when it began: a body built again since is not
    /// the one the cut was prepared for.
    mesh: Arc<TetMesh>,
    settings: BodySettings,
    heat: Option<(HeatParams, HeatBoundary)>,
    work: Work,
}

#[derive(Debug)]
enum Work {
    Ready(Prepared),
    Thread(std::thread::JoinHandle<Prepared>),
    /// On one thread of the world's pool (the others step): the input waits in `slot`
    /// until that thread or the landing step takes it.
    Pool {
        slot: PoolSlot,
        /// (In a mutex so a job can sit in shared state, a Bevy resource.)
        rx: std::sync::Mutex<std::sync::mpsc::Receiver<Prepared>>,
        done: Arc<AtomicBool>,
    },
}

/// A pool preparation's input, until taken. A job dropped before its thread started (a
/// reset) takes it back, so the thread does nothing.
#[derive(Debug)]
struct PoolSlot(Arc<std::sync::Mutex<Option<Input>>>);

impl PoolSlot {
    fn take(&self) -> Option<Input> {
        self.0.lock().ok().and_then(|mut s| s.take())
    }
}

impl Drop for PoolSlot {
    fn drop(&mut self) {
        drop(self.take());
    }
}

/// Where a cut is prepared ([`WorldBody::begin_cut_at`]).
#[derive(Debug, Clone, Copy)]
pub enum CutPlace<'a> {
    /// Within the call.
    Here,
    /// On a thread of its own at a lower priority (nice 10).
    Thread,
    /// On a thread lent by this pool ([`crate::parallel::Threads::lend`]): the steps go
    /// on on its other threads. On a thread of its own where the pool has none to spare (or
    /// is a single thread).
    Pool(&'a crate::parallel::Threads),
}

// A job sits in shared state (a Bevy resource): it must stay Send and Sync.
const _: fn() = || {
    fn shareable<T: Send + Sync>() {}
    shareable::<CutJob>();
};

impl CutJob {
    /// Whether its preparation is done (landing it does not wait).
    pub fn is_ready(&self) -> bool {
        match &self.work {
            Work::Ready(_) => true,
            Work::Thread(h) => h.is_finished(),
            Work::Pool { done, .. } => done.load(Ordering::Acquire),
        }
    }
}

/// Prepares `input` on a thread `threads` lends; `Err` gives it back where none is spare.
fn prepare_in_pool(threads: &crate::parallel::Threads, input: Input) -> Result<Work, Box<Input>> {
    let slot = Arc::new(std::sync::Mutex::new(Some(input)));
    let (tx, rx) = std::sync::mpsc::channel();
    let done = Arc::new(AtomicBool::new(false));
    let (theirs, flag) = (slot.clone(), done.clone());
    let lent = threads.lend(move || {
        let input = theirs.lock().ok().and_then(|mut s| s.take());
        if let Some(input) = input {
            // A panic ends here: the landing step sees the channel close.
            if let Ok(p) = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| prepare(input)))
            {
                let _ = tx.send(p);
            }
        }
        flag.store(true, Ordering::Release);
    });
    match lent {
        Ok(()) => Ok(Work::Pool {
            slot: PoolSlot(slot),
            rx: std::sync::Mutex::new(rx),
            done,
        }),
        Err(job) => {
            // Not lent: the job never ran and its copy of the slot goes with it.
            drop(job);
            let input = match Arc::try_unwrap(slot) {
                Ok(m) => m.into_inner().unwrap_or_else(|e| e.into_inner()),
                Err(shared) => shared.lock().unwrap_or_else(|e| e.into_inner()).take(),
            };
            match input {
                Some(input) => Err(Box::new(input)),
                None => Ok(Work::Ready(Prepared::Missed)),
            }
        }
    }
}

/// What a cut needs of its body, taken when it began.
#[derive(Debug, Clone)]
struct Input {
    name: String,
    mesh: Arc<TetMesh>,
    x: Vec<Vec3>,
    settings: BodySettings,
    heat: Option<(HeatParams, HeatBoundary)>,
    history: Option<CutHistory>,
    origin: (String, f64, u32),
    pieces_made: usize,
    change: Change,
    options: CutOptions,
    /// Nodes the last contact solve pressed on (their neighbourhoods' compliance columns
    /// are computed with the new bodies, see [`warm_touched`]; empty for a change made in
    /// the step, whose contact computes what it needs).
    touched: Vec<u32>,
    /// The body's frame (where it was moved to): the new bodies take it before their
    /// columns are computed.
    frame: nalgebra::Isometry3<f64>,
}

/// What a prepared change of the mesh does.
#[derive(Debug, Clone)]
enum Change {
    /// A blade's strips cut (see [`recut_within`]).
    Blade {
        blade: Vec<CutTriangle>,
        region: Vec<CutTriangle>,
        incision: u64,
    },
    /// Balls of vaporized tissue are carved out of the rest shape.
    Carve(Vec<Ball>),
}

/// A prepared cut.
#[derive(Debug)]
enum Prepared {
    /// Nothing to cut (a warning said why, where the shape could not be cut).
    Missed,
    /// Crossed, nothing separated.
    Crossed,
    Cut(Box<PreparedCut>),
}

#[derive(Debug)]
struct PreparedCut {
    separated: usize,
    bisected: usize,
    /// Each node of the cut mesh as a point of a tetrahedron before.
    origins: Vec<NodeOrigin>,
    /// Each piece's nodes (cut mesh indices) and its body, at rest; the kept piece first.
    parts: Vec<(Vec<u32>, WorldBody)>,
    node_map: Vec<(u32, u32)>,
    /// The balls a carve took out (empty for a blade's cut).
    carved: Vec<Ball>,
}

impl WorldBody {
    /// Cuts the body along `blade` (triangles in scene coordinates, where the body is now).
    /// Returns `None` when nothing was separated (the body is unchanged). Otherwise the body
    /// becomes the piece holding most of its fixed nodes (the largest when none is fixed),
    /// each other piece is returned as a new body named `NAME.k`, and every piece is at its
    /// precise level in the state the body was cut in (see the module docs). A refused cut
    /// leaves the body as it was.
    pub fn cut(
        &mut self,
        blade: &[CutTriangle],
        options: &CutOptions,
    ) -> Result<Option<BladeCut>, WorldError> {
        Ok(match self.cut_within(blade, &[], 0, options)? {
            BladeOutcome::Cut(c) => Some(*c),
            _ => None,
        })
    }

    /// [`WorldBody::cut`] by the pending strips `blade` of incision `incision` ([`Incision::id`])
    /// whose stroke so far is `region` (see [`crate::mesh::cut::recut_within`]).
    pub fn cut_within(
        &mut self,
        blade: &[CutTriangle],
        region: &[CutTriangle],
        incision: u64,
        options: &CutOptions,
    ) -> Result<BladeOutcome, WorldError> {
        match self.begin_cut(blade, region, incision, options, false)? {
            Some(job) => self.finish_cut(job),
            None => Ok(BladeOutcome::Missed),
        }
    }

    /// Begins [`WorldBody::cut_within`]: takes the body's shape now and prepares the cut,
    /// here or (`background`) on a thread of its own. `None`: the blade does not reach the
    /// body. A blade with bad values is refused by name.
    pub fn begin_cut(
        &mut self,
        blade: &[CutTriangle],
        region: &[CutTriangle],
        incision: u64,
        options: &CutOptions,
        background: bool,
    ) -> Result<Option<CutJob>, WorldError> {
        let place = if background {
            CutPlace::Thread
        } else {
            CutPlace::Here
        };
        self.begin_cut_at(blade, region, incision, options, place)
    }

    /// [`WorldBody::begin_cut`], prepared where `place` says.
    pub fn begin_cut_at(
        &mut self,
        blade: &[CutTriangle],
        region: &[CutTriangle],
        incision: u64,
        options: &CutOptions,
        place: CutPlace<'_>,
    ) -> Result<Option<CutJob>, WorldError> {
        let err = |b: &WorldBody, reason: String| WorldError::Cut {
            body: b.label(),
            reason,
        };
        if !(crate::mesh::cut::MIN_SNAP..0.5).contains(&options.snap) {
            let e = crate::mesh::cut::CutError::BadSnap(options.snap);
            return Err(err(self, e.to_string()));
        }
        crate::mesh::cut::check_blade(blade)
            .and_then(|_| crate::mesh::cut::check_blade(region))
            .map_err(|e| err(self, e.to_string()))?;
        if blade.is_empty() || !self.blade_reaches(blade) {
            return Ok(None);
        }
        let change = Change::Blade {
            blade: blade.to_vec(),
            region: region.to_vec(),
            incision,
        };
        self.begin_change(change, options, place).map(Some)
    }

    /// Begins carving the balls `balls` (tissue an electrode vaporized, in the rest shape;
    /// see [`WorldBody::vaporized`]) out of the body as a cut changes the mesh: prepared where
    /// `place` says, landed by [`WorldBody::finish_cut`], the pieces left (usually one) in the
    /// state of the step it lands in, their masses by their share of the volume (the mass of
    /// what was carved leaves). `None` when `balls` is empty.
    pub fn begin_vaporize(
        &mut self,
        balls: Vec<Ball>,
        options: &CutOptions,
        place: CutPlace<'_>,
    ) -> Result<Option<CutJob>, WorldError> {
        if balls.is_empty() {
            return Ok(None);
        }
        if let Some(b) = balls.iter().find(|b| {
            !(b.radius.is_finite() && b.radius > 0.0 && b.centre.iter().all(|c| c.is_finite()))
        }) {
            return Err(WorldError::Cut {
                body: self.label(),
                reason: format!("a ball to carve is not finite or has no size: {b:?}"),
            });
        }
        self.begin_change(Change::Carve(balls), options, place)
            .map(Some)
    }

    fn begin_change(
        &mut self,
        change: Change,
        options: &CutOptions,
        place: CutPlace<'_>,
    ) -> Result<CutJob, WorldError> {
        let (x, _) = self.model.node_state().map_err(|e| self.precision_err(e))?;
        let surface = self.collider.nodes();
        let mut touched: Vec<u32> = if matches!(place, CutPlace::Here) {
            Vec::new()
        } else {
            self.contact_load
                .iter()
                .filter_map(|&(v, _)| surface.get(v as usize).copied())
                .collect()
        };
        touched.sort_unstable();
        touched.dedup();
        let input = Input {
            touched,
            frame: self.frame,
            name: self.name.clone(),
            mesh: self.mesh.clone(),
            x,
            settings: self.model.settings().clone(),
            heat: self
                .heat
                .as_ref()
                .map(|h| (*h.params(), self.heat_boundary.clone())),
            history: self.cut.as_ref().map(|c| c.history.clone()),
            origin: self.cut.as_ref().map_or_else(
                || (self.name.clone(), self.mesh.volume(), 0),
                |c| (c.origin.clone(), c.origin_volume, c.cuts),
            ),
            pieces_made: self.pieces_made,
            change,
            options: *options,
        };
        let (mesh, settings, heat) = (
            input.mesh.clone(),
            input.settings.clone(),
            input.heat.clone(),
        );
        let pooled = match place {
            CutPlace::Pool(threads) => prepare_in_pool(threads, input),
            _ => Err(Box::new(input)),
        };
        let work = match pooled {
            Ok(work) => work,
            Err(input) => self.prepare_elsewhere(*input, !matches!(place, CutPlace::Here)),
        };
        Ok(CutJob {
            mesh,
            settings,
            heat,
            work,
        })
    }

    /// A cut's preparation in the step, or (`background`) on a thread of its own.
    fn prepare_elsewhere(&self, input: Input, background: bool) -> Work {
        if background {
            // A thread of its own, not the world's pool, at a lower priority: the steps go on
            // beside it.
            let (tx, rx) = std::sync::mpsc::channel::<Input>();
            let spawned = std::thread::Builder::new()
                .name("soft-tissue cut".into())
                .spawn(move || {
                    // It yields a core to the steps (and a haptic loop).
                    if let Err(e) = crate::haptics::priority::background() {
                        log::debug!("a cut's thread kept its priority: {e}");
                    }
                    match rx.recv() {
                        Ok(input) => prepare(input),
                        Err(_) => Prepared::Missed,
                    }
                });
            match spawned {
                Ok(handle) => {
                    // Sent once the thread exists, so a refused spawn keeps the input.
                    let _ = tx.send(input);
                    Work::Thread(handle)
                }
                Err(e) => {
                    log::warn!("body `{}`: cut prepared in the step: {e}", self.name);
                    Work::Ready(prepare(input))
                }
            }
        } else {
            Work::Ready(prepare(input))
        }
    }

    /// Lands a cut begun by [`WorldBody::begin_cut`] (waiting for its thread if it is not
    /// done): the body's state now (positions, velocities, temperature, damage) goes to the
    /// pieces by the weights of their nodes. A body built again since the cut began is not
    /// the one it was prepared for: the cut is dropped and reported as crossed (its strips
    /// cut again).
    pub fn finish_cut(&mut self, job: CutJob) -> Result<BladeOutcome, WorldError> {
        let started = std::time::Instant::now();
        let ready = job.is_ready();
        let prepared = match job.work {
            Work::Ready(p) => Some(p),
            Work::Thread(h) => h.join().ok(),
            Work::Pool { slot, rx, .. } => match slot.take() {
                // Not started yet: prepared here, now.
                Some(input) => Some(prepare(input)),
                None => rx.into_inner().ok().and_then(|rx| rx.recv().ok()),
            },
        };
        // Whatever the outcome, the step waited this long for the preparation (or made it).
        let wait_us = if ready {
            0.0
        } else {
            started.elapsed().as_secs_f64() * 1e6
        };
        self.landing_wait_us = wait_us;
        let Some(prepared) = prepared else {
            log::warn!(
                "body `{}`: not cut: the thread preparing the cut failed",
                self.name
            );
            return Ok(BladeOutcome::Missed);
        };
        let cut = match prepared {
            Prepared::Missed => return Ok(BladeOutcome::Missed),
            Prepared::Crossed => return Ok(BladeOutcome::Crossed),
            Prepared::Cut(c) => c,
        };
        let heat = self
            .heat
            .as_ref()
            .map(|h| (*h.params(), self.heat_boundary.clone()));
        if !Arc::ptr_eq(&self.mesh, &job.mesh)
            || self.model.settings() != &job.settings
            || heat != job.heat
        {
            log::info!(
                "body `{}`: a cut prepared for it was dropped: the body was built again (or its heat changed) since",
                self.name
            );
            return Ok(BladeOutcome::Crossed);
        }
        let PreparedCut {
            separated,
            bisected,
            origins,
            parts,
            node_map,
            carved,
        } = *cut;
        // A carve that leaves one piece keeps the electrodes' spots going (`burn.rs`).
        let spots_go_on = !carved.is_empty() && parts.len() == 1;
        // Every field of the body now, carried to the new nodes.
        let (x, v) = self.model.node_state().map_err(|e| self.precision_err(e))?;
        let carry = |field: &[Vec3]| -> Vec<Vec3> {
            origins.iter().map(|o| o.interpolate(field)).collect()
        };
        let x_all = carry(&x);
        let v_all = carry(&v);
        // Where the supports hold their nodes (moved kinematically or not), whatever the level.
        let held_all = carry(self.model.precise().positions());
        // Where the tissue has moved since the cut began, a piece's element may be turned
        // inside out in the state of now: the cut is dropped and its strips cut again.
        for (nodes, body) in &parts {
            let inverted = body.mesh.tets().iter().any(|t| {
                let [a, b, c, d] = t.map(|i| x_all[nodes[i as usize] as usize]);
                (b - a).cross(&(c - a)).dot(&(d - a)) <= 0.0
            });
            if inverted {
                log::warn!(
                    "body `{}`: a cut dropped: an element of it would be inverted where the body is now",
                    self.name
                );
                return Ok(BladeOutcome::Crossed);
            }
        }
        let heat_all = self.heat.as_ref().map(|h| {
            // The electrodes' spots give their heat to the nodes (the pieces start without
            // spots; burnt volumes and the heat the water took start again in them), but
            // where a carve leaves one piece they go on in its field (`burn::carry_spots`).
            let now = if spots_go_on {
                h.temperatures().to_vec()
            } else {
                h.temperatures_with_spots()
            };
            let t: Vec<f64> = origins.iter().map(|o| o.interpolate(&now)).collect();
            let d: Vec<f64> = origins.iter().map(|o| o.interpolate(h.damage())).collect();
            (t, d)
        });
        let mut built = Vec::with_capacity(parts.len());
        for (nodes, mut body) in parts {
            let xp: Vec<Vec3> = nodes.iter().map(|&n| x_all[n as usize]).collect();
            let vp: Vec<Vec3> = nodes.iter().map(|&n| v_all[n as usize]).collect();
            body.model
                .pin(self.model.pinned())
                .map_err(|e| body.precision_err(e))?;
            body.model
                .start_precise(&xp, &vp)
                .map_err(|e| body.precision_err(e))?;
            // A support holds a piece's node where it held the node it came from.
            let precise = body.model.precise_mut();
            let fixed = precise.fixed().to_vec();
            for ((p, axes), &n) in precise.positions_mut().iter_mut().zip(&fixed).zip(&nodes) {
                for a in 0..3 {
                    if axes[a] {
                        p[a] = held_all[n as usize][a];
                    }
                }
            }
            if let (Some(h), Some((t, d))) = (body.heat.as_mut(), heat_all.as_ref()) {
                let r = h
                    .set_temperatures(|i| t[nodes[i] as usize])
                    .and_then(|_| h.set_damage(|i| d[nodes[i] as usize]));
                if r.is_ok()
                    && let Some(old) = self.heat.as_ref()
                {
                    // The kept piece goes on with the body's burns (volumes, the heat the
                    // water took); every piece with its marks (the burn stays drawn).
                    if spots_go_on {
                        burn::carry_spots(h, &body.mesh, old);
                        body.vaporize_tried = [&self.vaporize_tried[..], &carved].concat();
                    } else if built.is_empty() {
                        h.carry_burns_from(old);
                    } else {
                        h.carry_marks_from(old);
                    }
                }
                r.map_err(|source| WorldError::Heat {
                    body: body.label(),
                    source,
                })?;
            }
            body.prune_vaporize_tried();
            body.friction = self.friction;
            body.toughness = self.toughness;
            // What was set at run time beyond the settings.
            body.model
                .set_precise_cg_must_converge(self.model.cg_must_converge());
            if self.model.has_shadow() {
                body.set_shadow(true)?;
            }
            body.collider.gather(body.model.node_positions());
            body.start.copy_from_slice(body.collider.positions());
            body.write_surface()?;
            built.push(body);
        }
        // Heat the pieces do not hold left with the change (carved tissue, the spots given to
        // the nodes): counted on the kept piece.
        if let Some(old) = self.heat.as_ref() {
            let now: f64 = built
                .iter()
                .filter_map(|b| b.heat.as_ref())
                .map(|h| h.heat_content())
                .sum();
            if let Some(h) = built.first_mut().and_then(|b| b.heat.as_mut()) {
                h.add_departed(old.heat_content() - now);
            }
        }
        let land_us = started.elapsed().as_secs_f64() * 1e6;
        for b in &mut built {
            // The pieces replace this body: the step reads the wait from the one in its slot.
            b.landing_wait_us = wait_us;
            if let Some(r) = b.cut.as_mut() {
                r.land_us = land_us;
                r.wait_us = wait_us;
            }
        }
        // The parts take the frame the body was moved to before anything is swapped (a no-op
        // where the preparation gave it already), so a failure leaves the body as it was.
        for b in &mut built {
            b.adopt_frame(self.frame)?;
        }
        let count = built.len();
        let mut built = built.into_iter();
        let kept = built.next().expect("a cut leaves at least one piece");
        let made = self.pieces_made + count - 1;
        let loose = self.loose;
        let previous = Box::new(std::mem::replace(self, kept));
        self.pieces_made = made;
        self.loose = loose;
        let mut pieces: Vec<WorldBody> = built.collect();
        for p in &mut pieces {
            p.loose = true;
        }
        Ok(BladeOutcome::Cut(Box::new(BladeCut {
            separated,
            bisected,
            pieces,
            node_map,
            previous,
        })))
    }

    /// Whether the blade's bounds meet the body's (a cheap test before the cut).
    fn blade_reaches(&self, blade: &[CutTriangle]) -> bool {
        let Some(b) = crate::mesh::Aabb::from_points(self.model.node_positions()) else {
            return false;
        };
        let mut lo = Vec3::repeat(f64::INFINITY);
        let mut hi = Vec3::repeat(f64::NEG_INFINITY);
        for t in blade {
            for c in &t.corners {
                lo = lo.inf(c);
                hi = hi.sup(c);
            }
        }
        (0..3).all(|a| lo[a] <= b.max[a] && hi[a] >= b.min[a])
    }

    /// Fills the record's per-face and per-body figures from `sides`.
    fn finish_cut_record(&mut self, history: CutHistory) {
        let sides = &history.sides;
        let surface = self.mesh.surface();
        let p = self.mesh.positions();
        let mut faces = Vec::new();
        let mut area = 0.0;
        for (k, &(t, corner)) in surface.triangle_tets().iter().enumerate() {
            if sides[t as usize][corner as usize] {
                faces.push(k as u32);
                let [a, b, c] = surface.triangles()[k].map(|i| p[i as usize]);
                area += 0.5 * (b - a).cross(&(c - a)).norm();
            }
        }
        let mut smallest = f64::INFINITY;
        for tet in self.mesh.tets() {
            let corners = tet.map(|i| p[i as usize]);
            for a in crate::mesh::tet_dihedral_angles(&corners) {
                smallest = smallest.min(a);
            }
        }
        let closed = surface_closed(surface.triangles());
        if let Some(r) = self.cut.as_mut() {
            r.history = history;
            r.surface_faces = faces;
            r.area = area;
            r.smallest_dihedral_deg = smallest;
            r.closed = closed;
        }
    }
}

/// A mesh of `positions` and `tets`, refused (`Err` with why) where it does not build or
/// some tetrahedron is inverted.
fn upright(positions: Vec<Vec3>, tets: &[[u32; 4]], what: &str) -> Result<TetMesh, String> {
    let corners: Vec<[usize; 4]> = tets.iter().map(|t| t.map(|i| i as usize)).collect();
    let mesh = TetMesh::new(positions, corners).map_err(|e| format!("{what}: {e}"))?;
    if mesh
        .warnings()
        .iter()
        .any(|w| matches!(w, crate::mesh::MeshWarning::Reoriented { .. }))
    {
        return Err(format!("{what}: some tetrahedra are inverted"));
    }
    Ok(mesh)
}

/// Prepares a cut from what was taken of the body: the cut mesh, its pieces and their
/// bodies at rest. A shape that cannot be cut is passed by (a warning says why).
fn prepare(input: Input) -> Prepared {
    match try_prepare(input) {
        Ok(p) => p,
        Err((name, why)) => {
            log::warn!("body `{name}`: not cut this step: {why}");
            Prepared::Missed
        }
    }
}

fn try_prepare(input: Input) -> Result<Prepared, (String, String)> {
    let started = std::time::Instant::now();
    let name = input.name.clone();
    let fail = |why: String| (name.clone(), why);
    // Where its elements are turned inside out the body has no shape to cut along (the
    // rest mesh's topology at the positions now: the faces and edges are not derived again).
    let now = input
        .mesh
        .moved_to(input.x)
        .map_err(|e| fail(format!("its shape now: {e}")))?;
    let cut = match &input.change {
        Change::Blade {
            blade,
            region,
            incision,
        } => recut_within(
            &now,
            input.history.as_ref(),
            blade,
            region,
            *incision,
            &input.options,
        )
        .map_err(|e| fail(e.to_string()))?,
        // Craters are balls of the rest shape: carved there (the state follows by the
        // nodes' origins, as after a blade's cut).
        Change::Carve(balls) => crate::mesh::cut::carve_keeping(
            &input.mesh,
            input.history.as_ref(),
            balls,
            input.options.snap,
            &supports(
                input.mesh.node_count(),
                &input.settings.boundary,
                input.heat.as_ref().map(|h| &h.1),
            ),
        )
        .map_err(|e| fail(format!("carving vaporized tissue: {e}")))?,
    };
    if cut.separated == 0 {
        return Ok(if cut.bisected > 0 {
            Prepared::Crossed
        } else {
            Prepared::Missed
        });
    }
    let origins = cut.node_origin;
    let rest_all: Vec<Vec3> = origins
        .iter()
        .map(|o| o.interpolate(input.mesh.positions()))
        .collect();
    let parts = pieces(&cut.mesh).map_err(|e| fail(format!("its pieces: {e}")))?;
    let settings = &input.settings;
    let old_mesh = &input.mesh;
    let old_volumes = lumped_volumes(old_mesh);
    let held = held_axes(&settings.boundary, old_mesh.node_count());
    // The body keeps the piece with most fixed nodes, then the largest.
    let fixed_count = |p: &crate::mesh::pieces::Piece| {
        p.nodes
            .iter()
            .filter(|&&n| fixed_axes(&held, &origins[n as usize]).is_some())
            .count()
    };
    let keep = (0..parts.len())
        .max_by(|&a, &b| {
            (fixed_count(&parts[a]), parts[a].mesh.volume())
                .partial_cmp(&(fixed_count(&parts[b]), parts[b].mesh.volume()))
                .unwrap_or(std::cmp::Ordering::Equal)
        })
        .unwrap_or(0);
    let reach = touched_reach(old_mesh, &input.touched);
    let mut order: Vec<usize> = vec![keep];
    order.extend((0..parts.len()).filter(|&k| k != keep));
    let mut build_us = 0.0;
    let mut built = Vec::with_capacity(parts.len());
    let mut node_map = vec![(u32::MAX, u32::MAX); old_mesh.node_count()];
    for (slot, &k) in order.iter().enumerate() {
        let part = &parts[k];
        let rest: Vec<Vec3> = part.nodes.iter().map(|&n| rest_all[n as usize]).collect();
        let mesh = upright(rest, part.mesh.tets(), "a piece's rest shape").map_err(&fail)?;
        let new_volumes = lumped_volumes(&mesh);
        let mut piece_settings = settings.clone();
        // Masses are given per body: each piece takes its share by volume.
        let share = mesh.volume() / old_mesh.volume();
        piece_settings.fem.mass *= share;
        piece_settings.msd.mass *= share;
        piece_settings.cage_msd.mass *= share;
        // The MSD's damping is per node: the same damping rate on nodes of the piece's
        // mass (its share of the mass over its nodes, against the body's per node).
        let per_node = share * old_mesh.node_count() as f64 / mesh.node_count() as f64;
        piece_settings.msd.damping *= per_node;
        piece_settings.cage_msd.damping *= share;
        piece_settings.boundary = carried_boundary(
            &settings.boundary,
            &held,
            &origins,
            &part.nodes,
            &old_volumes,
            &new_volumes,
        );
        let heat = input.heat.as_ref().map(|(params, boundary)| {
            let fixed =
                carried_heat_boundary(boundary, &origins, &part.nodes, old_mesh.node_count());
            (*params, fixed)
        });
        let piece_name = if slot == 0 {
            input.name.clone()
        } else {
            format!("{}.{}", input.name, input.pieces_made + slot)
        };
        let building = std::time::Instant::now();
        let mut body = WorldBody::build(piece_name, Arc::new(mesh), piece_settings, heat, false)
            .map_err(|e| fail(format!("building a piece: {e}")))?;
        // In the frame the body was moved to (as landing would put it), so the columns
        // are those of the body that lands.
        body.adopt_frame(input.frame)
            .map_err(|e| fail(format!("moving a piece to the body's frame: {e}")))?;
        // Only an optimisation: a failure leaves the columns to the landing step.
        let warmed = warm_touched(&mut body, &reach).unwrap_or_else(|e| {
            log::warn!("body `{name}`: no contact columns computed for a piece: {e}");
            0
        });
        // An electrode's next spot in a crater asks what share of its surroundings is
        // tissue: the grid that answers is built here, not in the step that asks.
        if body.heat.is_some() && matches!(input.change, Change::Carve(_)) {
            body.occupancy.prepare(&body.mesh);
        }
        build_us += building.elapsed().as_secs_f64() * 1e6;
        let history = CutHistory {
            sides: part
                .tets
                .iter()
                .map(|&t| cut.history.sides[t as usize])
                .collect(),
            on_blade: part
                .nodes
                .iter()
                .map(|&n| cut.history.on_blade[n as usize])
                .collect(),
        };
        body.cut = Some(CutRecord {
            origin: input.origin.0.clone(),
            origin_volume: input.origin.1,
            cuts: input.origin.2 + 1,
            warmed_nodes: warmed,
            ..CutRecord::default()
        });
        body.finish_cut_record(history);
        for (local, &n) in part.nodes.iter().enumerate() {
            if let Some(o) = single_node(&origins[n as usize]) {
                let slot_map = &mut node_map[o as usize];
                if slot_map.0 == u32::MAX {
                    *slot_map = (slot as u32, local as u32);
                }
            }
        }
        built.push((part.nodes.clone(), body));
    }
    let whole_us = started.elapsed().as_secs_f64() * 1e6;
    for (_, b) in &mut built {
        if let Some(r) = b.cut.as_mut() {
            r.mesh_us = whole_us - build_us;
            r.build_us = build_us;
        }
    }
    Ok(Prepared::Cut(Box::new(PreparedCut {
        separated: cut.separated,
        bisected: cut.bisected,
        origins,
        parts: built,
        node_map,
        carved: match input.change {
            Change::Carve(balls) => balls,
            Change::Blade { .. } => Vec::new(),
        },
    })))
}

/// Most nodes a new body computes compliance columns for where the old one was touched.
const WARM_NODES: usize = 128;

/// Where the old body was touched, in its rest shape: each touched node's position and the
/// longest rest edge at it (a tool pressing on that node reaches the new nodes within its
/// elements).
fn touched_reach(mesh: &TetMesh, touched: &[u32]) -> Vec<(Vec3, f64)> {
    if touched.is_empty() {
        return Vec::new();
    }
    let p = mesh.positions();
    let mut longest = vec![0.0f64; p.len()];
    for &[a, b] in mesh.edges() {
        let l = (p[a as usize] - p[b as usize]).norm();
        longest[a as usize] = longest[a as usize].max(l);
        longest[b as usize] = longest[b as usize].max(l);
    }
    touched
        .iter()
        .filter(|&&k| (k as usize) < p.len())
        .map(|&k| (p[k as usize], longest[k as usize]))
        .collect()
}

/// Computes a new body's compliance columns for its surface nodes (rest shape) within the
/// reach of where the old body was touched, nearest first, at most [`WARM_NODES`] (and what
/// its column cache holds): the contact of the step it lands in then finds them kept
/// instead of solving for them. Returns the nodes whose columns were computed.
fn warm_touched(body: &mut WorldBody, reach: &[(Vec3, f64)]) -> Result<usize, PrecisionError> {
    if reach.is_empty() {
        return Ok(0);
    }
    let rest = body.mesh.positions();
    let mut near: Vec<(f64, u32)> = body
        .collider
        .nodes()
        .iter()
        .filter_map(|&k| {
            let x = rest[k as usize];
            reach
                .iter()
                .filter_map(|&(c, r)| {
                    let d = (x - c).norm();
                    (d <= r).then_some(d / r.max(1e-300))
                })
                .min_by(f64::total_cmp)
                .map(|d| (d, k))
        })
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    near.truncate(WARM_NODES);
    let nodes: Vec<u32> = near.into_iter().map(|(_, k)| k).collect();
    body.model.warm_contact_columns(&nodes)
}
