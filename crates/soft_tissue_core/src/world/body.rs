//! [`WorldBody`]: one simulated body, its levels, contact surface, heat field and outputs.

use super::*;

/// Most precise steps [`WorldBody::new`] spends settling a body under gravity.
pub const SETTLE_STEPS: u32 = 5000;

/// One simulated body: its levels, contact surface, optional heat field and outputs.
#[derive(Debug)]
pub struct WorldBody {
    pub(crate) name: String,
    pub(crate) mesh: Arc<TetMesh>,
    /// Where the mechanics sit relative to `mesh` (see [`WorldBody::frame`]).
    pub(crate) frame: nalgebra::Isometry3<f64>,
    pub(crate) model: LeveledModel,
    pub(crate) collider: SurfaceCollider,
    pub(crate) heat: Option<HeatField>,
    /// The heat field's fixed temperatures (a cut carries them over).
    pub(crate) heat_boundary: HeatBoundary,
    /// The cuts this body came from (see [`WorldBody::cut`]).
    pub(crate) cut: Option<super::cut::CutRecord>,
    /// Pieces this body gave off in cuts (their names count on from it).
    pub(crate) pieces_made: usize,
    /// Balls of vaporized tissue whose carving was tried (refused, or carved: a crater is
    /// carved again once it has grown by [`super::CARVE_GROWTH`]); only the largest at each
    /// crater there is now is kept ([`WorldBody::prune_vaporize_tried`]).
    pub(crate) vaporize_tried: Vec<crate::mesh::cut::Ball>,
    /// The rest mesh's tetrahedra by place, for an electrode's tissue fraction (built when
    /// the first spot starts; see [`super::burn::tissue_fraction_in`]).
    pub(crate) occupancy: crate::mesh::occupancy::Occupancy,
    /// Room for the coarse nodes an electrode heats on this body and their weights (kept
    /// between steps: a pressed electrode allocates nothing).
    pub(crate) electrode_nodes: Vec<(usize, f64)>,
    /// How long the last landing of a cut on this body waited for its preparation,
    /// microseconds, whatever it came to ([`WorldBody::landing_wait_us`]).
    pub(crate) landing_wait_us: f64,
    /// A piece that came loose in a cut (a world's reset removes it).
    pub(crate) loose: bool,
    pub(crate) rest_surface: Vec<Vec3>,
    pub(crate) surface_out: Vec<[f32; 3]>,
    pub(crate) diagnostics: BodyDiagnostics,
    /// Surface friction.
    pub(crate) friction: Friction,
    /// Fracture toughness (see [`WorldBody::set_toughness`]).
    pub(crate) toughness: f64,
    // Per-step contact bookkeeping and workspaces.
    pub(crate) touched: bool,
    pub(crate) contacts: u32,
    pub(crate) active: bool,
    /// Surface positions at the start of the step (friction reads the motion since).
    pub(crate) start: Vec<Vec3>,
    /// Largest distance a surface vertex moved in the step (detection reaches that much
    /// deeper).
    pub(crate) moved: f64,
    /// Deepest penetration and contacts with a force in this step's contact solve.
    pub(crate) penetration: f64,
    pub(crate) solve_contacts: u32,
    /// The contact forces of the last step on surface vertices (collider indices): loads of
    /// this step's free motion (see [`solve_contacts`]).
    pub(crate) contact_load: Vec<(u32, Vec3)>,
    pub(crate) node_scratch: Vec<u32>,
    pub(crate) force_scratch: Vec<(u32, Vec3)>,
    /// The surface was last written while the body slept (nothing to write again).
    pub(crate) written_asleep: bool,
    /// The last writeback wrote the surface (it changed, or may have).
    pub(crate) surface_written: bool,
    /// This step's solver failure, when the bodies stepped in parallel (reported in body
    /// order after all of them ran).
    pub(crate) step_error: Option<WorldError>,
    /// This body's state before the contact solve first changed it this step (put back
    /// when the stage fails).
    pub(crate) undo: LevelSnapshot,
}

impl WorldBody {
    /// Builds a body from a mesh (in scene coordinates) and its settings; `heat` adds a
    /// temperature field stepped at `settings.dt`.
    pub fn new(
        name: impl Into<String>,
        mesh: Arc<TetMesh>,
        settings: BodySettings,
        heat: Option<(HeatParams, HeatBoundary)>,
    ) -> Result<Self, WorldError> {
        Self::build(name.into(), mesh, settings, heat, true)
    }

    /// [`WorldBody::new`], settling under gravity only when `settle` (a piece of a cut body
    /// starts in the state it was cut in instead).
    pub(crate) fn build(
        name: String,
        mesh: Arc<TetMesh>,
        settings: BodySettings,
        heat: Option<(HeatParams, HeatBoundary)>,
        settle: bool,
    ) -> Result<Self, WorldError> {
        let dt = settings.dt;
        let precision = |source| WorldError::Precision {
            body: name.clone().into(),
            source,
        };
        let settings_method = settings.precise;
        let mut body = LeveledModel::new(&mesh, settings).map_err(precision)?;
        // Under gravity the cage level starts from the equilibrium the precise method finds
        // (a free body finds it on its supports in the world: it starts precise).
        let settled = if settle {
            body.settle(&mesh, SETTLE_STEPS).map_err(precision)?.1
        } else {
            true
        };
        if body.falls() {
            body.raise().map_err(precision)?;
        }
        if !settled {
            log::warn!(
                "body `{name}` did not come to rest under its loads within {SETTLE_STEPS} steps; its cage holds the last shape"
            );
        }
        let mut collider = SurfaceCollider::new(&mesh).map_err(|source| WorldError::Contact {
            name: name.clone().into(),
            source,
        })?;
        collider.gather(body.node_positions());
        let (heat, heat_boundary) = match heat {
            Some((params, boundary)) => (
                Some(
                    HeatField::new(&mesh, params, dt, &boundary).map_err(|source| {
                        WorldError::Heat {
                            body: name.clone().into(),
                            source,
                        }
                    })?,
                ),
                boundary,
            ),
            None => (None, HeatBoundary::default()),
        };
        let rest_surface = collider.positions().to_vec();
        let start = rest_surface.clone();
        let mut b = WorldBody {
            surface_out: vec![[0.0; 3]; rest_surface.len()],
            rest_surface,
            diagnostics: BodyDiagnostics {
                level: Level::Cage,
                method: settings_method,
                step_us: 0.0,
                switch_us: 0.0,
                cg: None,
                unconverged_solves: 0,
                contacts: 0,
                max_penetration: 0.0,
                touched: false,
                switch_count: 0,
                switched: None,
                last_switch: None,
                max_displacement: 0.0,
                max_temperature: heat.as_ref().map(|h| h.max_temperature()),
                heat_us: 0.0,
                shadow: None,
            },
            name,
            mesh,
            frame: nalgebra::Isometry3::identity(),
            model: body,
            collider,
            heat,
            heat_boundary,
            cut: None,
            pieces_made: 0,
            vaporize_tried: Vec::new(),
            occupancy: Default::default(),
            electrode_nodes: Vec::new(),
            landing_wait_us: 0.0,
            loose: false,
            friction: Friction::default(),
            toughness: 0.0,
            touched: false,
            contacts: 0,
            active: false,
            start,
            moved: 0.0,
            penetration: 0.0,
            solve_contacts: 0,
            contact_load: Vec::new(),
            node_scratch: Vec::new(),
            force_scratch: Vec::new(),
            written_asleep: false,
            surface_written: false,
            step_error: None,
            undo: LevelSnapshot::default(),
        };
        b.write_surface()?;
        Ok(b)
    }

    /// Name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// A number no other body of this process has (its contact surface's), which errors
    /// carry ([`WorldError::body_id`]).
    pub fn id(&self) -> u64 {
        self.collider.id()
    }

    /// The name and id errors about this body carry.
    pub fn label(&self) -> BodyName {
        BodyName {
            name: self.name.clone(),
            id: Some(self.id()),
        }
    }

    /// The tetrahedral mesh: the rest shape in the coordinates the body was built in, those
    /// of its heat field, cuts and burns. A body moved since ([`WorldBody::teleport`]) has
    /// its mechanics at this mesh moved by [`WorldBody::frame`] ([`WorldBody::rest_mesh`]).
    pub fn mesh(&self) -> &Arc<TetMesh> {
        &self.mesh
    }

    /// The levels.
    pub fn model(&self) -> &LeveledModel {
        &self.model
    }

    /// The levels, to pin, change method or push.
    pub fn model_mut(&mut self) -> &mut LeveledModel {
        &mut self.model
    }

    /// Contact surface.
    pub fn collider(&self) -> &SurfaceCollider {
        &self.collider
    }

    /// Heat field, if the body has one.
    pub fn heat(&self) -> Option<&HeatField> {
        self.heat.as_ref()
    }

    /// Heat field, to heat or cool.
    pub fn heat_mut(&mut self) -> Option<&mut HeatField> {
        self.heat.as_mut()
    }

    /// Surface friction (default [`Friction::default`]).
    pub fn friction(&self) -> &Friction {
        &self.friction
    }

    /// Sets the surface friction; refused, naming the body and field, when invalid.
    pub fn set_friction(&mut self, friction: Friction) -> Result<(), WorldError> {
        friction
            .validate(&self.name)
            .map_err(|source| WorldError::Contact {
                name: self.label(),
                source,
            })?;
        self.friction = friction;
        Ok(())
    }

    /// Surface positions written by [`writeback`] (order of the collider's vertices, the
    /// surface vertices of the mesh), `f32` for rendering.
    pub fn surface_positions(&self) -> &[[f32; 3]] {
        &self.surface_out
    }

    /// Whether the last writeback wrote the surface positions (false only for a body asleep
    /// since an earlier writeback: nothing of its surface changed).
    pub fn surface_written(&self) -> bool {
        self.surface_written
    }

    /// Mesh node of each entry of [`WorldBody::surface_positions`].
    pub fn surface_nodes(&self) -> &[u32] {
        self.collider.nodes()
    }

    /// Surface triangles, indexing [`WorldBody::surface_positions`].
    pub fn surface_triangles(&self) -> &[[u32; 3]] {
        self.collider.triangles()
    }

    /// What the last step did.
    pub fn diagnostics(&self) -> &BodyDiagnostics {
        &self.diagnostics
    }

    /// Turns on or off a shadow precise simulation beside the cage level, for validation:
    /// [`BodyDiagnostics::shadow`] then reports the distance between the two each step
    /// (see [`LeveledModel::set_shadow`]; it costs one precise step per step).
    pub fn set_shadow(&mut self, on: bool) -> Result<(), WorldError> {
        let mesh = self.rest_mesh()?;
        self.model
            .set_shadow(&mesh, on)
            .map_err(|source| WorldError::Precision {
                body: self.label(),
                source,
            })?;
        self.diagnostics.shadow = self.model.shadow_error();
        Ok(())
    }

    /// Changes the body's materials at run time (see [`LeveledModel::set_materials`]: no
    /// jump, the precise solver built again). The parameters are this body's: for a piece
    /// of a cut body, its share of the masses (see [`CutRecord::share`](super::CutRecord::share)).
    pub fn set_materials(
        &mut self,
        fem: crate::material::FemParams,
        msd: crate::material::MsdParams,
        springs: crate::msd::SpringStiffness,
    ) -> Result<(), WorldError> {
        let mesh = self.rest_mesh()?;
        self.model
            .set_materials(&mesh, fem, msd, springs)
            .map_err(|e| self.precision_err(e))?;
        self.written_asleep = false;
        Ok(())
    }

    /// Gives the body a new temperature field, or removes it (`None`). A new field starts
    /// at its parameters' initial temperature, with no damage.
    pub fn set_heat(&mut self, heat: Option<(HeatParams, HeatBoundary)>) -> Result<(), WorldError> {
        self.vaporize_tried.clear();
        self.heat = match heat {
            Some((params, boundary)) => {
                let field = HeatField::new(&self.mesh, params, self.model.settings().dt, &boundary)
                    .map_err(|source| WorldError::Heat {
                        body: self.label(),
                        source,
                    })?;
                self.heat_boundary = boundary;
                Some(field)
            }
            None => None,
        };
        self.written_asleep = false;
        Ok(())
    }

    /// Writes the surface positions and the diagnostics. A non-finite surface position is
    /// never written: the surface keeps its last positions and the error names the node.
    pub(crate) fn write_surface(&mut self) -> Result<(), WorldError> {
        self.diagnostics.level = self.model.level();
        self.diagnostics.shadow = if self.model.level() == Level::Cage {
            self.model.shadow_error()
        } else {
            None
        };
        self.diagnostics.switch_count = self.model.switch_count();
        self.diagnostics.last_switch = self.model.last_switch();
        if self.heat.is_none() && self.model.is_asleep() && self.written_asleep {
            // Asleep and already written: the surface has not changed.
            self.surface_written = false;
            return Ok(());
        }
        let x = self.model.node_positions();
        if let Some(&node) = self
            .collider
            .nodes()
            .iter()
            .find(|&&i| !x[i as usize].iter().all(|c| c.is_finite()))
        {
            self.surface_written = false;
            self.diagnostics.max_displacement = f64::NAN;
            return Err(WorldError::NonFinite {
                body: self.label(),
                node: node as usize,
                stage: "writeback",
            });
        }
        self.surface_written = true;
        self.written_asleep = self.model.is_asleep();
        let mut max_d: f64 = 0.0;
        for ((o, &i), r) in self
            .surface_out
            .iter_mut()
            .zip(self.collider.nodes())
            .zip(&self.rest_surface)
        {
            let p = x[i as usize];
            *o = [p.x as f32, p.y as f32, p.z as f32];
            max_d = crate::state::nan_max(max_d, (p - r).norm());
        }
        self.diagnostics.max_displacement = max_d;
        self.diagnostics.level = self.model.level();
        self.diagnostics.method = self.model.settings().precise;
        self.diagnostics.switch_count = self.model.switch_count();
        self.diagnostics.last_switch = self.model.last_switch();
        self.diagnostics.max_temperature = self.heat.as_ref().map(|h| h.max_temperature());
        Ok(())
    }

    /// At the precise level and not yet slow for the policy's rest steps.
    pub(crate) fn moving(&self) -> bool {
        self.model.is_moving()
    }

    pub(crate) fn precision_err(&self, source: PrecisionError) -> WorldError {
        WorldError::Precision {
            body: self.label(),
            source,
        }
    }

    /// Back to the initial state (cage level, rest shape, initial temperature).
    pub fn reset(&mut self) -> Result<(), WorldError> {
        self.model.reset().map_err(|e| self.precision_err(e))?;
        if let Some(h) = &mut self.heat {
            h.reset();
        }
        self.vaporize_tried.clear();
        self.collider.reset_motion(self.model.node_positions());
        self.touched = false;
        self.contacts = 0;
        self.penetration = 0.0;
        self.solve_contacts = 0;
        self.contact_load.clear();
        self.start.copy_from_slice(self.collider.positions());
        self.diagnostics.switched = None;
        self.diagnostics.step_us = 0.0;
        self.diagnostics.switch_us = 0.0;
        self.diagnostics.contacts = 0;
        self.diagnostics.max_penetration = 0.0;
        self.diagnostics.touched = false;
        self.diagnostics.unconverged_solves = 0;
        self.written_asleep = false;
        self.write_surface()
    }
}

impl WorldBody {
    /// Saves this body's level state before the contact solve first changes it this step
    /// (see [`solve_contacts`]).
    pub(crate) fn before_change(&mut self) {
        if !self.undo.is_saved() {
            self.model.save_level_state(&mut self.undo);
        }
    }

    /// The compliance blocks between surface vertices `vertices` (collider indices) of the
    /// step just taken (see [`LeveledModel::contact_compliance`]).
    pub(crate) fn contact_compliance(
        &mut self,
        vertices: &[u32],
        out: &mut [nalgebra::Matrix3<f64>],
    ) -> Result<(), WorldError> {
        self.node_scratch.clear();
        let nodes = self.collider.nodes();
        self.node_scratch
            .extend(vertices.iter().map(|&v| nodes[v as usize]));
        self.model
            .contact_compliance(&self.node_scratch, out)
            .map_err(|e| self.precision_err(e))
    }

    /// Corrects the step by contact forces on surface vertices (collider indices; see
    /// [`LeveledModel::apply_contact_forces`]).
    pub(crate) fn apply_contact_forces(
        &mut self,
        forces: &[(u32, Vec3)],
    ) -> Result<(), WorldError> {
        self.force_scratch.clear();
        let nodes = self.collider.nodes();
        self.force_scratch
            .extend(forces.iter().map(|&(v, f)| (nodes[v as usize], f)));
        let r = self.model.apply_contact_forces(&self.force_scratch);
        self.written_asleep = false;
        r.map_err(|e| self.precision_err(e))
    }
}
