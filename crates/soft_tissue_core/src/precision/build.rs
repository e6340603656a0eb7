//! Building a leveled model's parts: its cage (box or fitted, with the calibrated model
//! projected from the precise one) and its precise solver.

use super::*;

impl LeveledModel {
    /// Replaces the cage: its fit and the workspaces sized by it follow.
    pub(super) fn install_cage(&mut self, cage: CageModel) -> Result<(), PrecisionError> {
        let nv = cage.cage().vertices().len();
        let nf = cage.cage().triangles().len();
        self.fit = SurfaceFit::new(cage.coordinates(), &self.surface)?;
        self.fit_cage = cage.cage_positions().to_vec();
        self.equilibrium = cage.cage().vertices().to_vec();
        self.fit_velocity = vec![Vec3::zeros(); nv];
        self.cage = cage;
        self.dent.forget();
        self.cage_work = vec![Vec3::zeros(); nv];
        self.terms_work = vec![Vec3::zeros(); nf];
        self.rate_work = vec![Vec3::zeros(); nf];
        Ok(())
    }
}

/// Node positions for the cage: nodes no tetrahedron uses (real meshes have them; they carry
/// no physics) stand at a used node's place, so they neither stretch the cage nor fall
/// outside it.
pub(super) fn cage_points(mesh: &TetMesh, positions: &[Vec3]) -> Vec<Vec3> {
    let used = |i: usize| !mesh.node_tets(i).is_empty();
    let mut points = positions.to_vec();
    if let Some(stand_in) = (0..points.len()).find(|&i| used(i)) {
        for (i, p) in points.iter_mut().enumerate() {
            if !used(i) {
                *p = positions[stand_in];
            }
        }
    }
    points
}

/// The cage body of the settings' kind around the nodes of `mesh` at `positions` (its surface
/// for fitted cages), embedding every node (see [`cage_points`]).
pub(super) fn build_cage(
    mesh: &TetMesh,
    positions: &[Vec3],
    settings: &BodySettings,
    precise: &Precise,
) -> Result<CageModel, PrecisionError> {
    let nodes = &cage_points(mesh, positions)[..];
    let triangles = mesh.surface().triangles();
    let options = FitOptions::for_points(
        nodes,
        match settings.cage {
            CageKind::BoundingBox => 8,
            CageKind::Fitted { vertices } => vertices,
        },
    );
    let cage_shape = match settings.cage {
        CageKind::BoundingBox => box_cage(nodes, options.margin)?,
        CageKind::Fitted { .. } => fitted_cage(nodes, triangles, &options)?,
    };
    let mut cage_config = CageModelConfig::paper(settings.dt);
    if settings.cage_dynamics == CageDynamics::Calibrated {
        let mut body = CageModel::new(cage_shape, nodes, &cage_config)?;
        let model = calibrated_model(mesh, nodes, &body, settings, precise)?;
        body.set_reduced(Some(model), settings.dt)?;
        return Ok(body);
    }
    cage_config.msd.stiffness = settings.cage_msd.stiffness;
    cage_config.msd.mass = settings.cage_msd.mass;
    cage_config.msd.damping = settings.cage_msd.damping;
    // A body held in place (anchored or fixed) cannot drift as a whole at the precise level;
    // its cage, whose springs resist only changes of shape, gets soft anchors to its rest so
    // its rigid motions are held too, at the rate the body's own supports give: the anchors'
    // total stiffness over the body's mass, or for fixed nodes the cage springs' own rate.
    let nv = cage_shape.vertices().len();
    let vertex_mass = settings.cage_msd.mass / nv as f64;
    let body_mass = if settings.precise.is_fem() {
        settings.fem.mass
    } else {
        settings.msd.mass
    };
    let anchor_total: f64 = settings
        .boundary
        .anchors
        .iter()
        .map(|&(_, k)| k.max(0.0))
        .sum();
    let rate = if !settings.boundary.fixed.is_empty() {
        settings.cage_msd.stiffness / vertex_mass
    } else if anchor_total > 0.0 && body_mass > 0.0 {
        anchor_total / body_mass
    } else {
        0.0
    };
    let boundary = if rate > 0.0 && rate.is_finite() {
        Boundary::anchored(nv, rate * vertex_mass)
    } else {
        Boundary::free()
    };
    Ok(CageModel::with_boundary(
        cage_shape,
        nodes,
        &cage_config,
        &boundary,
    )?)
}

/// The cage dynamics projected from `precise` linearised at `nodes` (see
/// [`ReducedModel`]), from the process-wide cache when an identical body (same nodes, mesh,
/// cage, method, material and supports) was built before.
pub(super) fn calibrated_model(
    mesh: &TetMesh,
    nodes: &[Vec3],
    cage: &CageModel,
    settings: &BodySettings,
    precise: &Precise,
) -> Result<std::sync::Arc<ReducedModel>, PrecisionError> {
    let body = precise.model();
    // Linearised where the cage's points stand at rest (unused nodes carry no stiffness).
    let x = nodes.to_vec();
    let anchor_k = &body.nodes().anchor_k;
    let free =
        !body.fixed().iter().any(|f| f.iter().any(|&b| b)) && anchor_k.iter().all(|&k| k == 0.0);
    let mut key = ModelKey::default();
    key.add(settings.precise.name())
        .floats(nodes.iter().flat_map(|p| p.iter().copied()))
        .add(mesh.tets())
        .floats(
            cage.cage()
                .vertices()
                .iter()
                .flat_map(|p| p.iter().copied()),
        )
        .add(cage.cage().triangles())
        .floats(body.masses().iter().copied())
        .floats(anchor_k.iter().copied())
        .add(body.fixed());
    let key = match precise {
        Precise::Fem(b) => {
            let c = b.config();
            key.floats([
                c.young_modulus,
                c.poisson_ratio,
                c.mass_damping,
                c.stiffness_damping,
            ])
        }
        Precise::Msd(b) => {
            // The springs themselves: their stiffnesses come from the constant or from a
            // material.
            let c = b.config();
            key.floats([c.mass, c.damping, c.volume_stiffness])
                .floats(
                    b.springs()
                        .iter()
                        .flat_map(|s| [s.stiffness, s.rest_length]),
                )
                .add(b.springs().iter().map(|s| [s.a, s.b]).collect::<Vec<_>>())
        }
    }
    .finish();
    let coords = cage.coordinates().clone();
    let model = cached_model(key, || {
        let masses = body.masses();
        let fixed = body.fixed();
        // The precise model's `K u` and its damping `(alpha, beta, gamma)`.
        type Mul<'a> = Box<dyn FnMut(&[Vec3], &mut [Vec3]) + 'a>;
        let (mut mul, damping): (Mul<'_>, (f64, f64, f64)) = match precise {
            Precise::Fem(b) => {
                let k = b.stiffness_at(&x, b.model());
                let c = b.config();
                (
                    Box::new(move |u: &[Vec3], out: &mut [Vec3]| k.mul(u, out)),
                    (c.mass_damping, c.stiffness_damping, 0.0),
                )
            }
            Precise::Msd(b) => {
                // K u by central differences of the spring, volume and anchor forces.
                let size = mesh.bbox().diagonal();
                let (mut xp, mut fp, mut fm) = (
                    x.clone(),
                    vec![Vec3::zeros(); x.len()],
                    vec![Vec3::zeros(); x.len()],
                );
                let x = &x;
                (
                    Box::new(move |u: &[Vec3], out: &mut [Vec3]| {
                        let umax = u.iter().map(|v| v.amax()).fold(0.0, f64::max);
                        if umax == 0.0 {
                            out.fill(Vec3::zeros());
                            return;
                        }
                        let eps = 1e-6 * size / umax;
                        for ((p, x0), ui) in xp.iter_mut().zip(x).zip(u) {
                            *p = x0 + ui * eps;
                        }
                        b.spring_forces(&xp, &mut fp);
                        for ((p, x0), ui) in xp.iter_mut().zip(x).zip(u) {
                            *p = x0 - ui * eps;
                        }
                        b.spring_forces(&xp, &mut fm);
                        for ((o, a), m) in out.iter_mut().zip(&fp).zip(&fm) {
                            *o = (m - a) / (2.0 * eps);
                        }
                    }),
                    (0.0, 0.0, b.config().damping),
                )
            }
        };
        ReducedModel::project(
            cage.cage(),
            &coords,
            PreciseOperators {
                masses,
                fixed,
                stiffness: &mut *mul,
                damping,
                free,
            },
        )
    })?;
    Ok(model)
}

pub(super) fn build_precise(mesh: &TetMesh, s: &BodySettings) -> Result<Precise, PrecisionError> {
    Ok(match s.precise.solver() {
        Ok(model) => {
            let mut c = FemConfig::paper(&s.fem, s.dt);
            c.model = model;
            c.gravity = s.gravity;
            c.integrator = s.fem_integrator;
            Precise::Fem(Box::new(FemBody::new(mesh, c, &s.boundary)?))
        }
        Err(integrator) => {
            let mut c = MsdConfig::paper(&s.msd, s.dt);
            c.integrator = integrator;
            c.spring_stiffness = s.msd_spring_stiffness;
            c.gravity = s.gravity;
            Precise::Msd(Box::new(MsdBody::from_mesh(mesh, c, &s.boundary)?))
        }
    })
}
