//! The switches between the levels: up (the cage's exact evaluation and its rate handed to
//! the precise solver), down (the fitted cage takes over), and the jump each one records.

use super::*;

impl LeveledModel {
    pub(super) fn max_surface_jump(&self, before: &[Vec3]) -> f64 {
        let now = self.node_positions();
        self.surface
            .iter()
            .zip(before)
            .map(|(&i, b)| (now[i as usize] - b).norm())
            .fold(0.0, f64::max)
    }

    pub(super) fn snapshot_surface(&mut self) {
        let now = match self.level {
            Level::Cage => self.cage.points(),
            Level::Precise => self.precise.model().positions(),
        };
        for (o, &i) in self.surface_work.iter_mut().zip(&self.surface) {
            *o = now[i as usize];
        }
    }

    pub(super) fn record(&mut self, from: Level, to: Level, residual: f64) -> SwitchRecord {
        let before = std::mem::take(&mut self.surface_work);
        let jump = self.max_surface_jump(&before);
        self.surface_work = before;
        let r = SwitchRecord {
            from,
            to,
            step: self.steps,
            jump,
            jump_ratio: jump / self.smallest,
            residual,
        };
        self.switches += 1;
        self.last_switch = Some(r);
        self.steps_at_level = 0;
        self.rest_count = 0;
        self.slow_steps = 0;
        self.asleep = false;
        r
    }

    /// Cage to precise (contact, or a pin). No effect at the precise level or when pinned to
    /// the cage. Returns the switch.
    pub fn raise(&mut self) -> Result<Option<SwitchRecord>, PrecisionError> {
        if self.level == Level::Precise || self.pin == Some(Level::Cage) {
            return Ok(None);
        }
        self.cage_state()?;
        if let Some((what, node)) =
            crate::state::first_non_finite_state(&self.nodes_work, &self.nodes_work2)
        {
            return Err(PrecisionError::NonFiniteSwitch {
                from: Level::Cage,
                what,
                node,
            });
        }
        self.snapshot_surface();
        let turned =
            self.cage_rotation(self.cage.cage_positions()) * self.lowered_rotation.inverse();
        load_state(
            &mut self.precise,
            &self.nodes_work,
            &self.nodes_work2,
            turned,
        );
        // The dent is now the precise model's shape.
        if self.cage.dent().is_some() {
            self.cage.clear_dent();
            self.cage.update_points()?;
        }
        // The cage this state came from is the exact fit of it: the next fit starts there.
        self.fit_cage.copy_from_slice(self.cage.cage_positions());
        self.fit_velocity
            .copy_from_slice(self.cage.msd().velocities());
        self.level = Level::Precise;
        Ok(Some(self.record(Level::Cage, Level::Precise, 0.0)))
    }

    /// The state the cage gives every node: positions (the exact map) into `nodes_work`,
    /// velocities (central difference of the exact map along the cage vertex velocities)
    /// into `nodes_work2`.
    pub(super) fn cage_state(&mut self) -> Result<(), PrecisionError> {
        let coords = self.cage.coordinates().clone();
        let x = self.cage.msd().positions();
        let u = self.cage.msd().velocities();
        coords.face_terms(x, &mut self.terms_work);
        coords.evaluate(x, &self.terms_work, &mut self.nodes_work)?;
        self.cage.add_detail(&mut self.nodes_work);
        // The map is linear in (vertices, face terms): the velocity is the map of the vertex
        // velocities and the face terms' rate (central difference along them), one evaluation.
        let h = 1e-3 * self.settings.dt;
        shifted(x, u, h, &mut self.cage_work);
        coords.face_terms(&self.cage_work, &mut self.rate_work);
        shifted(x, u, -h, &mut self.cage_work);
        coords.face_terms(&self.cage_work, &mut self.terms_work);
        for (r, t) in self.rate_work.iter_mut().zip(&self.terms_work) {
            *r = (*r - t) / (2.0 * h);
        }
        coords.evaluate(u, &self.rate_work, &mut self.nodes_work2)?;
        Ok(())
    }

    /// Precise to cage (rest, or a pin). No effect at the cage level or when pinned to the
    /// precise level. Returns the switch.
    pub fn lower(&mut self) -> Result<Option<SwitchRecord>, PrecisionError> {
        if self.level == Level::Cage || self.pin == Some(Level::Precise) {
            return Ok(None);
        }
        let residual = self.fit_cage(MAX_FIT_ITERATIONS, super::fit::STEP_NEWTON_STEPS)?;
        self.lower_fitted(residual).map(Some)
    }

    /// The down-switch onto the converged fit (`residual` its error).
    pub(super) fn lower_fitted(&mut self, residual: f64) -> Result<SwitchRecord, PrecisionError> {
        self.fit_velocities(MAX_FIT_ITERATIONS);
        if let Some((what, node)) =
            crate::state::first_non_finite_state(&self.fit_cage, &self.fit_velocity)
        {
            return Err(PrecisionError::NonFiniteSwitch {
                from: Level::Precise,
                what,
                node,
            });
        }
        self.snapshot_surface();
        self.residual = residual;
        // Loads waiting for the precise level's next step (a contact's, say) are not the
        // cage's: the cage holds the shape they held.
        self.precise
            .model_mut()
            .external_forces_mut()
            .fill(Vec3::zeros());
        self.lowered_rotation = self.cage_rotation(&self.fit_cage);
        let msd = self.cage.msd_mut();
        msd.positions_mut().copy_from_slice(&self.fit_cage);
        msd.velocities_mut().copy_from_slice(&self.fit_velocity);
        // The cage keeps its rest shape (the body's equilibrium, see `settle`): whatever
        // motion is left carries on at the cage level and its springs bring it back to rest.
        // A free body under gravity rests on its supports in a shape of its own, which its
        // cage (without gravity) keeps.
        // So does a body held in a pressed shape by its neighbours (see `set_held`); one that
        // rests free of them goes back to its rest shape.
        if self.falls() || self.held || self.rests_loaded {
            self.cage.rebase_equilibrium(true);
            self.equilibrium.copy_from_slice(&self.fit_cage);
            self.rebased = true;
        } else if self.rebased {
            self.cage.rebase_equilibrium(false);
            self.equilibrium
                .copy_from_slice(self.cage.cage().vertices());
            self.rebased = false;
        }
        // What the cage does not reproduce of the shape stays as a detail on top of it, so
        // the switch does not move the surface at all (a neighbour pressed against it is not
        // kicked by the fit's residual), and a free body keeps the shape it rests in.
        self.cage.set_detail(None)?;
        self.cage.exact_points(&mut self.nodes_work)?;
        self.cage
            .set_detail_between(self.precise.model().positions(), &self.nodes_work)?;
        self.cage.update_points()?;
        // The shadow carries on from the precise state the cage now stands for.
        self.restart_shadow()?;
        self.level = Level::Cage;
        Ok(self.record(Level::Precise, Level::Cage, residual))
    }
}

/// Sets a precise solver's nodes to `x`, `v`; components it holds fixed keep their position
/// and get no velocity.
pub(super) fn load_state(
    target: &mut Precise,
    x: &[Vec3],
    v: &[Vec3],
    turned: UnitQuaternion<f64>,
) {
    let nodes = target.model_mut().nodes_mut();
    for i in 0..nodes.x.len() {
        for a in 0..3 {
            if !nodes.fixed[i][a] {
                nodes.x[i][a] = x[i][a];
                nodes.v[i][a] = v[i][a];
            } else {
                nodes.v[i][a] = 0.0;
            }
        }
    }
    // A state from elsewhere: BDF2 starts a new history. Element rotations matter to the
    // corotational model only (a switch to it syncs them).
    if let Precise::Msd(b) = target {
        b.restart_history();
    }
    if let Precise::Fem(b) = target {
        b.restart_history();
        if b.model().is_corotational() {
            b.sync_rotations_from(turned);
        }
    }
}
