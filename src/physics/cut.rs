//! The cut stage: every blade with cutting on cuts the bodies its incision crosses (the
//! core's [`WorldBody::begin_cut`] and [`WorldBody::finish_cut`], in the step or on a thread of
//! its own, landing `CutOptions::background_steps` steps later); the pieces that come
//! loose become entities of their own (those of a body with a [`VisualMesh`] drawn with a
//! subdivided one, so the burn marks they took along show). The balls a carve removed are
//! noted for the body's visual mesh (`render/carve.rs`).
//! It runs in [`SoftTissueSystems::Prepare`] before the prepare stage, so the pieces'
//! entities exist when this step's bodies are gathered.

use super::*;
use soft_tissue_core::mesh::cut::{Ball, CutTriangle};
use soft_tissue_core::scenario::Anchor;
use soft_tissue_core::world::{BladeOutcome, CutPlace, Incision, remap_grips};

use crate::render::{EmbeddedVisual, SoftBodyMesh};

/// `mesh` (world coordinates) in the frame of an entity placed at `placement` (the mesh as
/// it is where that map fails, which it does only for a placement that is not invertible).
fn local_mesh(mesh: &Arc<TetMesh>, placement: &GlobalTransform) -> Arc<TetMesh> {
    match mapped(mesh, placement.to_matrix().as_dmat4().inverse()) {
        Ok(m) => m,
        Err(e) => {
            warn!("a cut body's mesh kept in world coordinates: {e}");
            mesh.clone()
        }
    }
}

/// A body of the cut stage: its entity, description, simulation, whether it keeps its
/// uncut body, whether it is a piece, its share of the uncut body's mass.
type BodyItem<'a> = (
    Entity,
    Mut<'a, SoftBody>,
    Mut<'a, SoftBodyState>,
    bool,
    bool,
    Option<&'a CutShare>,
);

/// A piece a cut made, to spawn: the entity it came from, its share of the uncut body's
/// mass, its body, description, build inputs, placement, pose, and where each blade's
/// incision had its body's pending strips start when it was cut (blade, incision id,
/// first pending strip): the piece's start the same.
type Made = (
    Entity,
    f64,
    WorldBody,
    SoftBody,
    BuiltFrom,
    GlobalTransform,
    GlobalTransform,
    Vec<(Entity, u64, u64)>,
);

#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub(super) fn cut_stage(
    mut commands: Commands,
    mut bodies: Query<(
        Entity,
        &mut SoftBody,
        &mut SoftBodyState,
        Has<UncutBody>,
        Has<CutPiece>,
        Option<&CutShare>,
    )>,
    mut tools: Query<(Entity, &SoftTool, &mut ToolState)>,
    visuals: Query<&VisualMesh>,
    poses: TransformHelper,
    mut assets: ResMut<Assets<TetMeshAsset>>,
    mut next: ResMut<NextBodyOrder>,
    mut jobs: ResMut<CutJobs>,
    threads: Res<SoftTissueThreads>,
    config: Res<SoftTissueConfig>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let t = Instant::now();
    // Each cutting blade's incision, in tool order.
    // Blades (a tool whose shape just changed is made again by the prepare stage first).
    let mut order: SmallVec<[(u64, Entity); 4]> = tools
        .iter()
        .filter(|(_, spec, s)| {
            matches!(spec.shape, ToolShape::Blade { .. }) && s.tool.shape() == spec.shape
        })
        .map(|(e, _, s)| (s.order, e))
        .collect();
    order.sort_unstable();
    let mut blades: SmallVec<[(Entity, u64, Vec<CutTriangle>); 2]> = SmallVec::new();
    for (_, entity) in order {
        let Ok((_, spec, mut state)) = tools.get_mut(entity) else {
            continue;
        };
        // The pose and the switch now (the prepare stage sets the same again).
        let Some((position, rotation)) = tool_pose(&poses, entity) else {
            continue;
        };
        let state = &mut *state;
        let r = state
            .tool
            .set_pose_rotation(position, rotation)
            .and_then(|_| state.tool.set_cutting(spec.cut));
        if let Err(e) = r {
            fail(
                &mut status,
                stage_error(SoftTissueStage::Cut, "moving a blade", Some(entity), e),
            );
            continue;
        }
        match state.tool.blade_sweep().filter(|_| state.tool.cutting()) {
            None => state.incision = None,
            Some([from, to]) => {
                let incision = state.incision.get_or_insert_with(|| Incision::new(from));
                let stroke = incision.advance(to);
                blades.push((entity, incision.id(), stroke));
            }
        }
    }
    // An electrode's crater (tissue to remove) is checked without allocating.
    let craters = bodies
        .iter()
        .any(|(_, _, sim, ..)| sim.body.heat().is_some_and(|h| h.has_craters()));
    if blades.is_empty() && jobs.0.is_empty() && !craters {
        status.times.cut_us = 0.0;
        status.times.cut_wait_us = 0.0;
        return;
    }
    let mut list: Vec<BodyItem> = bodies.iter_mut().collect();
    list.sort_unstable_by_key(|(_, _, b, _, _, _)| b.order);
    let existing = list.len();
    let options = config.cut;
    let mut made: Vec<Made> = Vec::new();
    let steps = status.steps;
    // One call of `landed` with this stage's state, wherever a cut lands.
    macro_rules! land {
        ($i:expr, $outcome:expr, $from:expr, $carved:expr) => {
            landed(
                $i,
                $outcome,
                $from,
                $carved,
                &mut list,
                &mut made,
                &mut commands,
                &mut assets,
                &mut tools,
                &mut status,
            )
        };
    }
    // Cuts due land first, in the order they began, except that with
    // `CutOptions::land_when_ready` one not done yet waits for a later step; a body gone since drops its cut. A
    // failure stops the stage (the pieces cut before it are still spawned).
    let mut failed = false;
    let mut waited = 0.0;
    let mut k = 0;
    while k < jobs.0.len() {
        let pending = &jobs.0[k];
        if pending.due > steps || (options.land_when_ready && !pending.job.is_ready()) {
            k += 1;
            continue;
        }
        let job = jobs.0.remove(k);
        let Some(i) = list.iter().position(|b| b.0 == job.body) else {
            continue;
        };
        let outcome = list[i].2.body.finish_cut(job.job);
        waited += list[i].2.body.landing_wait_us();
        // Refused by the mesh: tried again once its balls have grown by `CARVE_GROWTH`
        // (dropped for now: next step).
        if !job.vaporized.is_empty() && matches!(outcome, Ok(BladeOutcome::Missed)) {
            list[i].2.body.vaporize_refused(&job.vaporized);
        }
        if !land!(
            i,
            outcome,
            (job.blade, job.incision, job.mark),
            &job.vaporized
        ) {
            failed = true;
            break;
        }
    }
    // Stops at the first failure, but the pieces cut before it are still spawned (their
    // bodies' kept parts were already replaced).
    let blades = if failed { &blades[..0] } else { &blades[..] };
    'blades: for (blade, id, stroke) in blades {
        for i in 0..existing {
            let entity = list[i].0;
            if jobs.0.iter().any(|j| j.body == entity) {
                continue;
            }
            let Ok((_, _, state)) = tools.get(*blade) else {
                break;
            };
            let Some((strips, mark)) = state
                .incision
                .as_ref()
                .filter(|inc| inc.id() == *id)
                .map(|inc| inc.pending(entity.to_bits()))
            else {
                break;
            };
            if strips.is_empty() {
                continue;
            }
            let background = options.background_steps > 0;
            let place = cut_place(background, &threads);
            let sim = &mut list[i].2;
            let outcome = match sim.body.begin_cut_at(&strips, stroke, *id, &options, place) {
                Ok(None) => Ok(BladeOutcome::Missed),
                Ok(Some(job)) if !background => sim.body.finish_cut(job),
                Ok(Some(job)) => {
                    jobs.0.push(PendingCut {
                        body: entity,
                        blade: *blade,
                        incision: *id,
                        mark,
                        due: steps + options.background_steps as u64,
                        job,
                        vaporized: Vec::new(),
                    });
                    continue;
                }
                Err(e) => Err(e),
            };
            if !land!(i, outcome, (*blade, *id, mark), &[]) {
                failed = true;
                break 'blades;
            }
        }
    }
    // Tissue electrodes vaporized leaves the bodies, as a cut changes them.
    if craters && !failed {
        for i in 0..existing {
            let entity = list[i].0;
            if jobs.0.iter().any(|j| j.body == entity) {
                continue;
            }
            let balls = list[i].2.body.vaporized();
            let background = options.background_steps > 0;
            let place = cut_place(background, &threads);
            let sim = &mut list[i].2;
            let outcome = match sim.body.begin_vaporize(balls.clone(), &options, place) {
                Ok(None) => continue,
                Ok(Some(job)) if !background => sim.body.finish_cut(job),
                Ok(Some(job)) => {
                    jobs.0.push(PendingCut {
                        body: entity,
                        blade: Entity::PLACEHOLDER,
                        incision: 0,
                        mark: 0,
                        due: steps + options.carve_steps() as u64,
                        job,
                        vaporized: balls,
                    });
                    continue;
                }
                Err(e) => Err(e),
            };
            if matches!(outcome, Ok(BladeOutcome::Missed)) {
                list[i].2.body.vaporize_refused(&balls);
            }
            if !land!(i, outcome, (Entity::PLACEHOLDER, 0, 0), &balls) {
                break;
            }
        }
    }
    for (from, share, body, spec, built_from, placement, pose, incision) in made {
        let name = Name::new(body.name().to_owned());
        let heat = body.heat().is_some();
        let visual = visuals.get(from).ok().map(piece_visual);
        let order = next.0;
        next.0 += 1;
        let mut source = commands.entity(from);
        let mut e = source.clone_and_spawn_with_opt_out(|b| {
            b.deny::<(
                Mesh3d,
                SoftBodyMesh,
                EmbeddedVisual,
                VisualMesh,
                VisualMeshError,
                UncutBody,
                CutPiece,
                GreenCage,
                Temperature,
            )>();
        });
        let mut state = SoftBodyState {
            body,
            order,
            dirty: true,
            placement,
            pose,
            to_local: None,
            built_from,
            shape: 0,
            reshaped: Default::default(),
        };
        state.set_pose(pose);
        e.insert((
            spec,
            CutShare(share),
            state,
            name,
            CutPiece { from },
            GreenCage::default(),
        ));
        if heat {
            e.insert(Temperature::default());
        }
        if let Some(visual) = visual {
            e.insert(visual);
        }
        // Every blade's strips pending for the body when it was cut are pending for the
        // piece (but not the strips that made it).
        let piece = e.id();
        for (blade, id, first) in incision {
            if let Ok((_, _, mut state)) = tools.get_mut(blade)
                && let Some(inc) = state.incision.as_mut().filter(|inc| inc.id() == id)
            {
                inc.consumed(piece.to_bits(), first);
            }
        }
    }
    status.times.cut_us = t.elapsed().as_secs_f64() * 1e6;
    status.times.cut_wait_us = waited;
}

/// Loop subdivision rounds of the visual mesh of a piece cut off a body drawn with a mesh of
/// the app's own (which does not fit the piece).
const PIECE_SUBDIVISION: u8 = 2;

/// The visual mesh of a piece cut off a body drawn with `visual`: its simulation surface
/// subdivided, as the body's was or [`PIECE_SUBDIVISION`] times, so the burn marks it took
/// along are drawn at its visual vertices (finer than its elements).
fn piece_visual(visual: &VisualMesh) -> VisualMesh {
    match visual {
        VisualMesh::Subdivided { levels } => VisualMesh::Subdivided { levels: *levels },
        VisualMesh::Mesh { .. } => VisualMesh::Subdivided {
            levels: PIECE_SUBDIVISION,
        },
    }
}

/// Where a cut is prepared: in the step, or (`background`) on a thread the solver stage's
/// pool lends where it has one to spare.
fn cut_place(background: bool, threads: &SoftTissueThreads) -> CutPlace<'_> {
    match (background, &threads.threads) {
        (false, _) => CutPlace::Here,
        (true, Some((_, pool))) => CutPlace::Pool(pool),
        (true, None) => CutPlace::Thread,
    }
}

/// Body `list[i]`'s cut by the incision `(blade, id, mark)` came to `outcome`: the kept
/// piece's mesh becomes the entity's, the pieces are queued in `made`, grips follow, and
/// the strips are no longer pending for the body unless they crossed it without
/// separating anything. `false`: the cut failed (the stage stops).
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
fn landed(
    i: usize,
    outcome: Result<BladeOutcome, soft_tissue_core::world::WorldError>,
    (blade, id, mark): (Entity, u64, u64),
    carved: &[Ball],
    list: &mut [BodyItem],
    made: &mut Vec<Made>,
    commands: &mut Commands,
    assets: &mut Assets<TetMeshAsset>,
    tools: &mut Query<(Entity, &SoftTool, &mut ToolState)>,
    status: &mut SoftTissueStatus,
) -> bool {
    let existing = list.len();
    let (entity, spec, sim, has_uncut, is_piece, share) = &mut list[i];
    let cut = match outcome {
        Ok(BladeOutcome::Cut(c)) => Some(*c),
        Ok(BladeOutcome::Crossed) => return true,
        Ok(BladeOutcome::Missed) => None,
        Err(e) => {
            fail(
                status,
                stage_error(SoftTissueStage::Cut, "cutting", Some(*entity), e),
            );
            return false;
        }
    };
    if let Ok((_, _, mut state)) = tools.get_mut(blade)
        && let Some(inc) = state.incision.as_mut().filter(|inc| inc.id() == id)
    {
        inc.consumed(entity.to_bits(), mark);
    }
    let Some(mut cut) = cut else {
        return true;
    };
    let sim = &mut **sim;
    // The kept body and the pieces were built where the body's mesh is: they go where the
    // body had moved.
    if let Err(e) = sim.body.carry_frame(&mut cut) {
        fail(
            status,
            stage_error(SoftTissueStage::Cut, "cutting", Some(*entity), e),
        );
        return false;
    }
    let placement = sim.placement;
    // Each part's share of the uncut body's mass: the share the body had (a body
    // built again after a cut keeps it only in `CutShare`) by volume.
    let per_volume = share.map_or(1.0, |s| s.0) / cut.previous.mesh().volume();
    if !*has_uncut && !*is_piece {
        commands.entity(*entity).insert(UncutBody {
            body: Some(cut.previous),
            mesh: spec.mesh.clone(),
            built_from: sim.built_from,
            pose: sim.pose,
        });
        *has_uncut = true;
    }
    // The kept piece's mesh becomes the entity's, in its frame (what a rebuild would
    // build again, with its share of the masses), without a change the prepare
    // stage would rebuild it for.
    let share = per_volume * sim.body.mesh().volume();
    let handle = assets.add(TetMeshAsset(local_mesh(sim.body.mesh(), &placement)));
    sim.built_from.mesh = handle.id();
    spec.bypass_change_detection().mesh = handle;
    sim.shape += 1;
    sim.dirty = true;
    // A visual mesh of the app's own follows a carve (not a blade's cut).
    if carved.is_empty() {
        sim.reshaped.cut();
    } else {
        sim.reshaped.carve(carved);
    }
    // Its cage is new: the component takes its triangles again.
    commands
        .entity(*entity)
        .insert((GreenCage::default(), CutShare(share)));
    let first = existing + made.len();
    // Where every blade's strips pending for the body start now (after this cut's).
    let pending: Vec<(Entity, u64, u64)> = tools
        .iter()
        .filter_map(|(e, _, state)| {
            let inc = state.incision.as_ref()?;
            Some((e, inc.id(), inc.pending_from(entity.to_bits())))
        })
        .collect();
    for piece in cut.pieces {
        let handle = assets.add(TetMeshAsset(local_mesh(piece.mesh(), &placement)));
        let mut piece_spec = (**spec).clone();
        piece_spec.mesh = handle.clone();
        // A piece holding none of the body's support is free.
        if piece.model().is_free() {
            piece_spec.anchor = Anchor::Free;
        }
        let mut built_from = sim.built_from;
        built_from.mesh = handle.id();
        built_from.anchor = piece_spec.anchor;
        made.push((
            *entity,
            per_volume * piece.mesh().volume(),
            piece,
            piece_spec,
            built_from,
            placement,
            sim.pose,
            pending.clone(),
        ));
    }
    // Grips on the body follow its nodes, into the pieces too.
    let lookup: Vec<&WorldBody> = list
        .iter()
        .map(|(_, _, b, _, _, _)| &b.body)
        .chain(made.iter().map(|m| &m.2))
        .collect();
    for (_, _, mut state) in tools.iter_mut() {
        let mut one = [&mut state.tool];
        remap_grips(&mut one, &lookup, i, &cut.node_map, first);
    }
    true
}
