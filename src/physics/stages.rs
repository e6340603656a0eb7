//! The systems of a step: reset, prepare (run-time changes), the core's stages and the
//! writeback of the read-out components.

use nalgebra::Isometry3;

use super::*;

/// A reset when asked for: every body and tool back to its initial state, counters and the
/// error cleared. Runs before the step, also while the simulation is paused or stopped by an
/// error.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub(super) fn reset_simulation(
    mut commands: Commands,
    mut requests: MessageReader<ResetSimulation>,
    mut bodies: Query<(
        Entity,
        &mut SoftBodyState,
        Option<&mut SoftBody>,
        Option<&mut UncutBody>,
        Has<CutPiece>,
    )>,
    mut tools: Query<&mut ToolState>,
    mut contacts: ResMut<SoftTissueContacts>,
    mut jobs: ResMut<CutJobs>,
    mut status: ResMut<SoftTissueStatus>,
    mut clock: ResMut<Time<SoftPhysics>>,
) {
    if requests.read().count() == 0 {
        return;
    }
    // Cuts being prepared are dropped (their threads end on their own).
    jobs.0.clear();
    status.steps = 0;
    status.error = None;
    status.recent.clear();
    for (e, mut b, spec, uncut, piece) in &mut bodies {
        // Pieces cut loose go; a cut body comes back whole.
        if piece {
            commands.entity(e).despawn();
            continue;
        }
        if let Some(mut uncut) = uncut
            && let Some(whole) = uncut.body.take()
        {
            b.body = *whole;
            b.built_from = uncut.built_from;
            // Where the body was when it was first cut: the prepare stage moves it to where
            // its entity is now.
            b.set_pose(uncut.pose);
            b.shape += 1;
            // The carves and cuts noted for the visual mesh were of the body before.
            b.reshaped.reset();
            if let Some(mut spec) = spec {
                spec.bypass_change_detection().mesh = uncut.mesh.clone();
            }
            commands
                .entity(e)
                .remove::<(UncutBody, CutShare)>()
                .insert(GreenCage::default());
        }
        if let Err(err) = b.body.reset() {
            fail(
                &mut status,
                stage_error(SoftTissueStage::Reset, "resetting", Some(e), err),
            );
            clock.pause();
        }
        b.dirty = true;
    }
    for mut tool in &mut tools {
        tool.tool.reset();
        tool.grabbing = false;
        tool.incision = None;
    }
    contacts.clear();
}

/// Whether two placements are the same to rounding.
fn same_placement(a: &GlobalTransform, b: &GlobalTransform) -> bool {
    a.affine().abs_diff_eq(b.affine(), 1e-6)
}

/// The rigid move (in double precision) that takes a body placed at `from` to `to`, when the
/// two differ by one: the same scale (to 1e-6 of it) and both made of a scale, a rotation
/// and a translation. `None` for a change of scale or a shear: the body is built again.
fn rigid_move(from: &GlobalTransform, to: &GlobalTransform) -> Option<Isometry3<f64>> {
    let parts = |g: &GlobalTransform| {
        let (s, r, t) = g.to_scale_rotation_translation();
        let rebuilt = bevy::math::Affine3A::from_scale_rotation_translation(s, r, t);
        rebuilt
            .abs_diff_eq(g.affine(), 1e-5 * s.abs().max_element().max(1.0))
            .then_some((s, r, t))
    };
    let ((s0, r0, t0), (s1, r1, t1)) = (parts(from)?, parts(to)?);
    if !s0.abs_diff_eq(s1, 1e-6 * s0.abs().max_element()) {
        return None;
    }
    let q = |r: Quat| {
        nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            r.w as f64, r.x as f64, r.y as f64, r.z as f64,
        ))
    };
    // The same rotation gives exactly none (a shift factors nothing).
    let turn = if r0 == r1 {
        nalgebra::UnitQuaternion::identity()
    } else {
        q(r1) * q(r0).inverse()
    };
    let (t0, t1) = (to_core(t0), to_core(t1));
    let shift = t1 - turn * t0;
    Some(Isometry3::from_parts(shift.into(), turn))
}

/// The prepare stage: run-time changes of the bodies' inputs (those that need a new body
/// are queued for building again), tool poses and actions, then the core's `prepare`. One
/// system, so the step pays one system's dispatch for all of it.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub(super) fn prepare_stage(
    mut commands: Commands,
    mut bodies: Query<(
        Entity,
        (
            Ref<SoftBody>,
            Ref<TissueMaterial>,
            Option<&TissueHeat>,
            Option<&SoftBodyTuning>,
            Option<&PinnedLevel>,
            Has<ShadowSimulation>,
            Option<&CutShare>,
        ),
        &mut SoftBodyState,
    )>,
    mut tools: Query<(Entity, &SoftTool, &mut ToolState)>,
    poses: TransformHelper,
    config: Res<SoftTissueConfig>,
    clock: Res<Time<SoftPhysics>>,
    mut contacts: ResMut<SoftTissueContacts>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    let dt = clock.timestep().as_secs_f64();
    // Bodies queued for a rebuild: gone before the next stage runs, so not among this step's
    // bodies (their indices would shift the contact indices of the bodies after them).
    let mut rebuilt: SmallVec<[Entity; 4]> = SmallVec::new();
    for (entity, (spec, material, heat, tuning, pin, shadow, share), mut sim) in &mut bodies {
        let now = BuiltFrom::of(&spec, tuning, dt, &config);
        // Computed from the transforms now (the entity's or a parent's may have been written
        // since the last propagation).
        let pose = poses
            .compute_global_transform(entity)
            .ok()
            .filter(|g| !same_placement(g, &sim.pose));
        // Moved rigidly: the whole state moves with it (a teleport). A change of scale
        // builds the body again at rest, as a change of its inputs does.
        let teleport = pose.and_then(|g| Some((g, rigid_move(&sim.pose, &g)?)));
        if now != sim.built_from || pose.is_some() && teleport.is_none() {
            // Built again at the next step, at rest, from the inputs then.
            commands.entity(entity).remove::<SoftBodyState>();
            rebuilt.push(entity);
            continue;
        }
        if let Some((g, m)) = teleport {
            match sim.body.teleport(m) {
                Ok(()) => {
                    sim.set_pose(g);
                    sim.dirty = true;
                }
                Err(e) => fail(
                    &mut status,
                    stage_error(SoftTissueStage::Prepare, "moving a body", Some(entity), e),
                ),
            }
        }
        let b = &mut sim.body;
        if spec.method != b.model().settings().precise {
            let was_fem = b.model().settings().precise.is_fem();
            match b.set_precise_method(spec.method) {
                // The state component follows the solver's kind.
                Ok(()) if was_fem != spec.method.is_fem() => {
                    let mut e = commands.entity(entity);
                    if spec.method.is_fem() {
                        e.insert(FemState::default()).remove::<MsdState>();
                    } else {
                        e.insert(MsdState::default()).remove::<FemState>();
                    }
                }
                Ok(()) => {}
                Err(e) => fail(
                    &mut status,
                    stage_error(
                        SoftTissueStage::Prepare,
                        "changing the method",
                        Some(entity),
                        e,
                    ),
                ),
            }
        }
        // A piece of a cut body comes with a cloned material, added with it: its masses
        // were given by the cut.
        if material.is_changed() && !(material.is_added() && share.is_some()) {
            // A cut body's share of the masses.
            let m = CutShare::of(share, &material);
            let (msd, springs) = m.msd_params(b.mesh().node_count());
            if let Err(e) = b.set_materials(m.fem, msd, springs) {
                fail(
                    &mut status,
                    stage_error(
                        SoftTissueStage::Prepare,
                        "changing the material",
                        Some(entity),
                        e,
                    ),
                );
            }
            if let Err(e) = b.set_friction(material.friction) {
                fail(
                    &mut status,
                    stage_error(
                        SoftTissueStage::Prepare,
                        "changing the friction",
                        Some(entity),
                        e,
                    ),
                );
            }
            if let Err(e) = b.set_toughness(material.toughness) {
                fail(
                    &mut status,
                    stage_error(
                        SoftTissueStage::Prepare,
                        "changing the toughness",
                        Some(entity),
                        e,
                    ),
                );
            }
        }
        let want_heat = heat.map(|h| h.0);
        if want_heat != b.heat().map(|h| *h.params()) {
            let had = b.heat().is_some();
            match b.set_heat(want_heat.map(|p| (p, HeatBoundary::insulated()))) {
                Ok(()) if want_heat.is_some() && !had => {
                    commands.entity(entity).insert(Temperature::default());
                }
                Ok(()) if want_heat.is_none() => {
                    commands.entity(entity).remove::<Temperature>();
                }
                Ok(()) => {}
                Err(e) => fail(
                    &mut status,
                    stage_error(
                        SoftTissueStage::Prepare,
                        "changing the heat",
                        Some(entity),
                        e,
                    ),
                ),
            }
            sim.dirty = true;
        }
        let b = &mut sim.body;
        let pinned: Option<Level> = pin.map(|p| p.0);
        if b.model().pinned() != pinned
            && let Err(e) = b.model_mut().pin(pinned)
        {
            fail(
                &mut status,
                stage_error(SoftTissueStage::Prepare, "pinning", Some(entity), e),
            );
        }
        if b.model().has_shadow() != shadow
            && let Err(e) = b.set_shadow(shadow)
        {
            fail(
                &mut status,
                stage_error(SoftTissueStage::Prepare, "shadow", Some(entity), e),
            );
        }
    }
    for (entity, spec, mut state) in &mut tools {
        let Some((position, rotation)) = tool_pose(&poses, entity) else {
            continue;
        };
        // A new shape: the tool is made again where it is (its grips let go).
        if state.tool.shape() != spec.shape {
            match Tool::new(state.tool.name().to_owned(), spec.shape) {
                Ok(t) => {
                    state.tool = t;
                    state.grabbing = false;
                    state.incision = None;
                }
                Err(e) => {
                    fail(
                        &mut status,
                        stage_error(SoftTissueStage::Prepare, "a tool's shape", Some(entity), e),
                    );
                    continue;
                }
            }
        }
        let t = &mut state.tool;
        if let Err(e) = t.set_pose_rotation(position, rotation) {
            fail(
                &mut status,
                stage_error(SoftTissueStage::Prepare, "moving a tool", Some(entity), e),
            );
            continue;
        }
        if *t.friction() != spec.friction
            && let Err(e) = t.set_friction(spec.friction)
        {
            fail(
                &mut status,
                stage_error(
                    SoftTissueStage::Prepare,
                    "a tool's friction",
                    Some(entity),
                    e,
                ),
            );
        }
        if let ToolShape::Grasper { .. } = spec.shape
            && t.target_opening() != spec.jaws.max(0.0)
            && let Err(e) = t.set_opening(spec.jaws)
        {
            fail(
                &mut status,
                stage_error(
                    SoftTissueStage::Prepare,
                    "a grasper's jaws",
                    Some(entity),
                    e,
                ),
            );
        }
        if t.cutting() != spec.cut
            && let Err(e) = t.set_cutting(spec.cut)
        {
            fail(
                &mut status,
                stage_error(SoftTissueStage::Prepare, "a blade's cut", Some(entity), e),
            );
        }
        if t.electrode_radius() != spec.electrode_radius
            && let Err(e) = t.set_electrode_radius(spec.electrode_radius)
        {
            fail(
                &mut status,
                stage_error(
                    SoftTissueStage::Prepare,
                    "a tool's electrode radius",
                    Some(entity),
                    e,
                ),
            );
        }
        if let Err(e) = t.set_cautery(spec.cautery_watts) {
            fail(
                &mut status,
                stage_error(
                    SoftTissueStage::Prepare,
                    "a tool's cautery",
                    Some(entity),
                    e,
                ),
            );
        }
        if spec.grab != state.grabbing {
            if spec.grab {
                state.tool.grab();
            } else {
                state.tool.release();
            }
            state.grabbing = spec.grab;
        }
    }
    let contacts = &mut *contacts;
    in_order(
        bodies
            .iter_mut()
            .filter(|(e, _, _)| !rebuilt.contains(e))
            .map(|(e, _, b)| (e, b)),
        tools.iter_mut().map(|(e, _, t)| (e, t)),
        Some((&mut contacts.bodies, &mut contacts.tools)),
        |b, tl| prepare(b, tl, dt),
    );
    status.times.prepare_us = lap(&mut t);
}

/// Runs `f` on the built bodies and the tools, each in build order, as the core's stage
/// functions take them (slices of `&mut`, so indices in the contact state stay valid).
/// With `entities`, writes the bodies' and tools' entities in that order.
fn in_order<'a, R>(
    bodies: impl Iterator<Item = (Entity, Mut<'a, SoftBodyState>)>,
    tools: impl Iterator<Item = (Entity, Mut<'a, ToolState>)>,
    entities: Option<(&mut Vec<Entity>, &mut Vec<Entity>)>,
    f: impl FnOnce(&mut [&mut WorldBody], &mut [&mut Tool]) -> R,
) -> R {
    let mut b: SmallVec<[(Entity, &mut SoftBodyState); 16]> =
        bodies.map(|(e, b)| (e, b.into_inner())).collect();
    b.sort_unstable_by_key(|(_, b)| b.order);
    let mut t: SmallVec<[(Entity, &mut ToolState); 4]> =
        tools.map(|(e, t)| (e, t.into_inner())).collect();
    t.sort_unstable_by_key(|(_, t)| t.order);
    if let Some((be, te)) = entities {
        be.clear();
        be.extend(b.iter().map(|(e, _)| *e));
        te.clear();
        te.extend(t.iter().map(|(e, _)| *e));
    }
    let mut b: SmallVec<[&mut WorldBody; 16]> = b.into_iter().map(|(_, b)| &mut b.body).collect();
    let mut t: SmallVec<[&mut Tool; 4]> = t.into_iter().map(|(_, t)| &mut t.tool).collect();
    f(&mut b, &mut t)
}

fn lap(t: &mut Instant) -> f64 {
    let e = t.elapsed().as_secs_f64() * 1e6;
    *t = Instant::now();
    e
}

/// A stage's result: a failure names the body the core's error is about, by entity (found
/// by the body's id, so two bodies of the same name, from two copies of a scene, are told
/// apart).
fn report<'a>(
    status: &mut SoftTissueStatus,
    stage: SoftTissueStage,
    what: &'static str,
    r: Result<(), WorldError>,
    mut bodies: impl Iterator<Item = (Entity, &'a SoftBodyState)>,
) {
    if let Err(e) = r {
        let body = e
            .body_id()
            .and_then(|id| bodies.find(|(_, b)| b.body.id() == id).map(|(e, _)| e));
        fail(status, stage_error(stage, what, body, e));
    }
}

pub(super) fn detect_stage(
    mut bodies: Query<(Entity, &mut SoftBodyState)>,
    mut tools: Query<(Entity, &mut ToolState)>,
    config: Res<SoftTissueConfig>,
    mut contacts: ResMut<SoftTissueContacts>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    in_order(bodies.iter_mut(), tools.iter_mut(), None, |b, tl| {
        detect_contacts(b, tl, &config.contact, &mut contacts.state)
    });
    status.times.detect_us = lap(&mut t);
}

/// The blades' pulls on the bodies of this step, from [`resistance_stage`] to
/// [`cut_load_stage`].
#[derive(Resource, Default)]
pub(crate) struct CutLoads(pub(crate) Vec<soft_tissue_core::world::CutLoad>);

/// Each cutting blade's resistance (the work of fracture of what it cuts) on the bodies as
/// the step begins, before the cut stage (a cut landing now would have opened the tissue the
/// blade went through); the blades are put where they are now first, as the cut stage does.
pub(super) fn resistance_stage(
    mut bodies: Query<(Entity, &mut SoftBodyState)>,
    mut tools: Query<(Entity, &SoftTool, &mut ToolState)>,
    poses: TransformHelper,
    mut loads: ResMut<CutLoads>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    for (entity, spec, mut state) in &mut tools {
        if !matches!(spec.shape, ToolShape::Blade { .. }) || state.tool.shape() != spec.shape {
            continue;
        }
        if let Some((position, rotation)) = build::tool_pose(&poses, entity) {
            // A failure is the cut stage's to report (it sets the same again).
            let state = &mut *state;
            let _ = state
                .tool
                .set_pose_rotation(position, rotation)
                .and_then(|_| state.tool.set_cutting(spec.cut));
        }
    }
    in_order(
        bodies.iter_mut(),
        tools.iter_mut().map(|(e, _, s)| (e, s)),
        None,
        |b, tl| cutting_resistance(tl, b, &mut loads.0),
    );
    status.times.cut_us += lap(&mut t);
}

/// The blades' pulls on the bodies, after the cut stage (on the bodies it left: a body it
/// cut keeps its place in the order).
pub(super) fn cut_load_stage(
    mut bodies: Query<(Entity, &mut SoftBodyState)>,
    mut tools: Query<(Entity, &mut ToolState)>,
    loads: Res<CutLoads>,
    mut status: ResMut<SoftTissueStatus>,
) {
    if loads.0.is_empty() {
        return;
    }
    let mut t = Instant::now();
    let r = in_order(bodies.iter_mut(), tools.iter_mut(), None, |b, _| {
        load_cutting(b, &loads.0)
    });
    report(
        &mut status,
        SoftTissueStage::Cut,
        "pulling the tissue a blade cuts",
        r,
        bodies.iter(),
    );
    status.times.cut_us += lap(&mut t);
}

pub(super) fn switch_stage(
    mut bodies: Query<(Entity, &mut SoftBodyState)>,
    mut tools: Query<(Entity, &mut ToolState)>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    let r = in_order(bodies.iter_mut(), tools.iter_mut(), None, |b, _| {
        switch_precision(b)
    });
    report(
        &mut status,
        SoftTissueStage::SwitchPrecision,
        "switching precision",
        r,
        bodies.iter(),
    );
    status.times.switch_us = lap(&mut t);
}

pub(super) fn solve_stage(
    mut bodies: Query<(Entity, &mut SoftBodyState)>,
    mut tools: Query<(Entity, &mut ToolState)>,
    contacts: Res<SoftTissueContacts>,
    config: Res<SoftTissueConfig>,
    mut pool: ResMut<SoftTissueThreads>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    if pool.threads.as_ref().map(|(asked, _)| *asked) != Some(config.threads) {
        let threads =
            soft_tissue_core::parallel::Threads::new(config.threads).unwrap_or_else(|e| {
                fail(
                    &mut status,
                    stage_error(
                        SoftTissueStage::StepSolvers,
                        "thread pool",
                        None,
                        SoftTissueStepError::ThreadPool(e),
                    ),
                );
                soft_tissue_core::parallel::Threads::single()
            });
        pool.threads = Some((config.threads, threads));
    }
    let threads = &pool.threads.as_ref().expect("set above").1;
    // With every body asleep there is nothing to share out: handing the stage to the pool
    // would cost more than the step (about 45 us a step on a 2-core VM for the organs at
    // rest). The result does not depend on where it runs.
    let awake = bodies.iter().any(|(_, b)| !b.body.model().is_asleep());
    let r = in_order(bodies.iter_mut(), tools.iter_mut(), None, |b, tl| {
        if awake {
            threads.run(|| step_solvers(b, tl, &contacts.state))
        } else {
            step_solvers(b, tl, &contacts.state)
        }
    });
    report(
        &mut status,
        SoftTissueStage::StepSolvers,
        "stepping the solvers",
        r,
        bodies.iter(),
    );
    status.times.solve_us = lap(&mut t);
}

pub(super) fn contact_stage(
    mut bodies: Query<(Entity, &mut SoftBodyState)>,
    mut tools: Query<(Entity, &mut ToolState)>,
    obstacles: Res<SoftTissueObstacles>,
    config: Res<SoftTissueConfig>,
    mut contacts: ResMut<SoftTissueContacts>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    let r = in_order(bodies.iter_mut(), tools.iter_mut(), None, |b, tl| {
        solve_contacts(
            b,
            tl,
            &obstacles.obstacles,
            &config.contact,
            &mut contacts.state,
        )
    });
    contacts.gather(&obstacles.entities);
    report(
        &mut status,
        SoftTissueStage::Collide,
        "solving the contacts",
        r,
        bodies.iter(),
    );
    let whole = lap(&mut t);
    status.times.correct_us = contacts.state.stats().correct_us.min(whole);
    status.times.contact_us = whole - status.times.correct_us;
}

#[allow(clippy::type_complexity)]
pub(super) fn writeback_stage(
    mut bodies: Query<(
        Entity,
        &mut SoftBodyState,
        &mut PrecisionLevel,
        &mut GreenCage,
        &mut SoftBodyDiagnostics,
        Option<&mut FemState>,
        Option<&mut MsdState>,
        Option<&mut Temperature>,
    )>,
    mut tools: Query<(&ToolState, &mut ToolReaction)>,
    mut level_changes: MessageWriter<LevelChanged>,
    mut touches: MessageWriter<BodyTouched>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let mut t = Instant::now();
    for (entity, mut sim, mut level, mut cage, mut diag, fem, msd, temp) in &mut bodies {
        // The core's writeback, body by body (bodies are independent here). A surface that
        // is not finite is not written (the mesh keeps its last positions) and stops the
        // simulation.
        if let Err(e) = sim.body.writeback() {
            fail(
                &mut status,
                stage_error(SoftTissueStage::Writeback, "writeback", Some(entity), e),
            );
            continue;
        }
        let b = &sim.body;
        let d = *b.diagnostics();
        let lb = b.model();
        let new_level = PrecisionLevel {
            level: d.level,
            method: lb.settings().precise,
            switches: d.switch_count,
            last_jump_ratio: d.last_switch.map(|s| s.jump_ratio),
        };
        if *level != new_level {
            *level = new_level;
        }
        // A sleeping body nothing touched changes nothing but its (tiny) step time.
        let quiet = lb.is_asleep()
            && !b.surface_written()
            && d.switched.is_none()
            && !d.touched
            && d.contacts == 0
            && b.heat().is_none_or(|h| {
                temp.as_ref()
                    .is_some_and(|t| t.version == Some(h.version()))
            })
            && !cage.vertices.is_empty();
        if quiet {
            if diag.step_us != d.step_us {
                diag.step_us = d.step_us;
            }
            continue;
        }

        if let Some(s) = d.switched {
            level_changes.write(LevelChanged {
                entity,
                from: s.from,
                to: s.to,
                jump_ratio: s.jump_ratio,
            });
        }
        if d.touched {
            touches.write(BodyTouched {
                entity,
                contacts: d.contacts,
            });
        }
        // Components change only when their contents do: the cage moves only at its own
        // level (or is handed over at a switch, or put back by a reset), temperatures only
        // while the field changes.
        let awake = !lb.is_asleep();
        let cage_moved = d.level == Level::Cage && (awake || b.surface_written());
        if cage_moved || d.switched.is_some() || cage.vertices.is_empty() {
            let c = lb.cage();
            cage.vertices.clear();
            cage.vertices.extend(c.cage_positions().iter().map(to_bevy));
            if cage.triangles.is_empty() {
                cage.triangles = c.cage().triangles().to_vec();
            }
            cage.active = d.level == Level::Cage;
        }
        diag.set_if_neq(SoftBodyDiagnostics {
            step_us: d.step_us + d.switch_us,
            contacts: d.contacts,
            max_penetration: d.max_penetration,
            penetration_ratio: d.max_penetration / lb.smallest_dimension(),
            max_displacement: d.max_displacement,
            shadow_error_ratio: d.shadow.map(|e| e.max_ratio),
            unconverged_solves: d.unconverged_solves,
            cut_faces: b.cut_record().map_or(0, |c| c.surface_faces.len() as u32),
            cut_area: b.cut_record().map_or(0.0, |c| c.area),
        });
        let cg = d.cg;
        if let (Some(mut f), Some(fb)) = (fem, lb.fem()) {
            f.set_if_neq(FemState {
                corotational: fb.model().is_corotational(),
                cg_iterations: cg.map_or(0, |c| c.iterations),
                cg_residual: cg.map_or(0.0, |c| c.relative_residual),
                cg_converged: cg.is_none_or(|c| c.converged),
            });
        }
        if let (Some(mut m), Some(mb)) = (msd, lb.msd()) {
            m.set_if_neq(MsdState {
                integrator: lb.settings().precise,
                substeps: mb.last_step().substeps,
                cg_iterations: cg.map_or(0, |c| c.iterations),
                cg_converged: cg.is_none_or(|c| c.converged),
            });
        }
        let mut heat_changed = false;
        if let (Some(mut tc), Some(h)) = (temp, b.heat())
            && tc.version != Some(h.version())
        {
            heat_changed = true;
            tc.version = Some(h.version());
            let nodes = b.surface_nodes();
            let temps = h.temperatures();
            tc.surface.clear();
            tc.surface
                .extend(nodes.iter().map(|&i| temps[i as usize] as f32));
            tc.damage.clear();
            tc.damage
                .extend(nodes.iter().map(|&i| h.damaged_fraction(i as usize) as f32));
            // NaN-propagating (`f64::min`/`max` would drop a NaN and show a sound range).
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for &v in temps {
                if v.is_nan() {
                    (lo, hi) = (f64::NAN, f64::NAN);
                    break;
                }
                (lo, hi) = (lo.min(v), hi.max(v));
            }
            let spots = h.max_temperature();
            if spots.is_nan() {
                (lo, hi) = (f64::NAN, f64::NAN);
            } else if !hi.is_nan() {
                hi = hi.max(spots);
            }
            (tc.min, tc.max) = (lo, hi);
            let v = h.burn_volumes();
            (tc.coagulated_mm3, tc.charred_mm3, tc.vaporized_mm3) =
                (v.coagulated * 1e9, v.charred * 1e9, v.vaporized * 1e9);
        }
        if awake || b.surface_written() || d.switched.is_some() || heat_changed {
            sim.dirty = true;
        }
    }
    for (state, mut reaction) in &mut tools {
        let t = &state.tool;
        *reaction = ToolReaction {
            force: to_bevy(&t.reaction_force()),
            cutting: to_bevy(&t.cutting_resistance()),
            contacts: t.contact_count(),
            grips: t.grips().len() as u32,
            opening: t.opening(),
            jaw_forces: t.jaw_forces(),
        };
    }
    status.times.writeback_us = lap(&mut t);
    let times = status.times;
    status.recent.push(&times);
    status.steps += 1;
}
