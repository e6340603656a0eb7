//! The cut stage: every blade with cutting on cuts the bodies its incision crosses (the
//! core's [`SimBody::cut`]); the pieces that come loose become entities of their own.
//! It runs in [`SoftTissueSystems::Prepare`] before the prepare stage, so the pieces'
//! entities exist when this step's bodies are gathered.

use super::*;
use soft_tissue_core::mesh::cut::{CutOptions, CutTriangle};
use soft_tissue_core::scenario::Anchor;
use soft_tissue_core::world::{BladeOutcome, Incision, remap_grips};

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

#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub(super) fn cut_stage(
    mut commands: Commands,
    mut bodies: Query<(
        Entity,
        &mut SoftBody,
        &mut SimulatedBody,
        Has<UncutBody>,
        Has<CutPiece>,
        Option<&CutShare>,
    )>,
    mut tools: Query<(Entity, &SoftTool, &mut ToolState)>,
    poses: TransformHelper,
    mut assets: ResMut<Assets<TetMeshAsset>>,
    mut next: ResMut<NextBodyOrder>,
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
    let mut blades: SmallVec<[(Entity, u64, Vec<CutTriangle>, Vec<CutTriangle>); 2]> =
        SmallVec::new();
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
                let id = incision.id();
                let (strip, stroke) = incision.advance(to);
                if !strip.is_empty() {
                    blades.push((entity, id, strip, stroke));
                }
            }
        }
    }
    if blades.is_empty() {
        status.times.cut_us = 0.0;
        return;
    }
    let mut list: Vec<_> = bodies.iter_mut().collect();
    list.sort_unstable_by_key(|(_, _, b, _, _, _)| b.order);
    let existing = list.len();
    let options = CutOptions::default();
    let mut made: Vec<(
        Entity,
        f64,
        SimBody,
        SoftBody,
        BuiltFrom,
        GlobalTransform,
        Option<Affine>,
    )> = Vec::new();
    // Stops at the first failure, but the pieces cut before it are still spawned (their
    // bodies' kept parts were already replaced).
    'blades: for (blade, id, strip, stroke) in &blades {
        let (mut crossed, mut cut_any) = (false, false);
        for i in 0..existing {
            let (entity, spec, sim, has_uncut, is_piece, share) = &mut list[i];
            let cut = match sim.body.cut_within(strip, stroke, *id, &options) {
                Ok(BladeOutcome::Cut(c)) => *c,
                Ok(BladeOutcome::Crossed) => {
                    crossed = true;
                    continue;
                }
                Ok(BladeOutcome::Missed) => continue,
                Err(e) => {
                    fail(
                        &mut status,
                        stage_error(SoftTissueStage::Cut, "cutting", Some(*entity), e),
                    );
                    break 'blades;
                }
            };
            cut_any = true;
            let sim = &mut **sim;
            let placement = sim.placement;
            // Each part's share of the uncut body's mass: the share the body had (a body
            // built again after a cut keeps it only in `CutShare`) by volume.
            let per_volume = share.map_or(1.0, |s| s.0) / cut.previous.mesh().volume();
            if !*has_uncut && !*is_piece {
                commands.entity(*entity).insert(UncutBody {
                    body: Some(cut.previous),
                    mesh: spec.mesh.clone(),
                    built_from: sim.built_from,
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
            // Its cage is new: the component takes its triangles again.
            commands
                .entity(*entity)
                .insert((GreenCage::default(), CutShare(share)));
            let first = existing + made.len();
            for piece in cut.pieces {
                let handle = assets.add(TetMeshAsset(local_mesh(piece.mesh(), &placement)));
                let mut piece_spec = (**spec).clone();
                piece_spec.mesh = handle.clone();
                // A piece holding none of the body's support is free.
                if piece.body().is_free() {
                    piece_spec.anchor = Anchor::None;
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
                    sim.to_local,
                ));
            }
            // Grips on the body follow its nodes, into the pieces too.
            let lookup: Vec<&SimBody> = list
                .iter()
                .map(|(_, _, b, _, _, _)| &b.body)
                .chain(made.iter().map(|m| &m.2))
                .collect();
            for (_, _, mut state) in &mut tools {
                let mut one = [&mut state.tool];
                remap_grips(&mut one, &lookup, i, &cut.node_map, first);
            }
        }
        // Strips that crossed a body without separating anything stay pending, unless they
        // cut another (they would cut that one again, wherever it moved).
        if (cut_any || !crossed)
            && let Ok((_, _, mut state)) = tools.get_mut(*blade)
            && let Some(inc) = state.incision.as_mut()
        {
            inc.kept();
        }
    }
    for (from, share, body, spec, built_from, placement, to_local) in made {
        let name = Name::new(body.name().to_owned());
        let heat = body.heat().is_some();
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
        e.insert((
            spec,
            CutShare(share),
            SimulatedBody {
                body,
                order,
                dirty: true,
                placement,
                to_local,
                built_from,
                shape: 0,
            },
            name,
            CutPiece { from },
            GreenCage::default(),
        ));
        if heat {
            e.insert(Temperature::default());
        }
    }
    status.times.cut_us = t.elapsed().as_secs_f64() * 1e6;
}

type Affine = bevy::math::Affine3A;
