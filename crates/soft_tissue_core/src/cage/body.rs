//! A body at the cage level: an MSD on the cage vertices and the body's points embedded by
//! Green coordinates.

use std::sync::Arc;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::green::{FastScratch, GreenCoordinates, coordinates_at};
use super::reduced::{ReducedModel, ReducedStepper};
use super::{Cage, CageError};
use crate::Vec3;
use crate::boundary::Boundary;
use crate::material::PAPER_CAGE_MSD;
use crate::msd::{MsdBody, MsdConfig, MsdIntegrator, Spring};
use crate::state::NodalModel;

/// Which springs join the cage vertices.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum CageSprings {
    /// Every pair of vertices when the cage has at most 12 (the box: its 12 edges, 12 face
    /// diagonals and 4 space diagonals), otherwise [`CageSprings::EdgesBendingStruts`].
    #[default]
    Auto,
    /// Every pair of vertices.
    Complete,
    /// Cage edges, one spring across every edge (joining the two opposite vertices, resists
    /// folding) and one strut per vertex to the vertex farthest along its inward normal
    /// (resists collapse).
    EdgesBendingStruts,
}

/// Settings of a [`CageModel`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CageModelConfig {
    /// The cage MSD (`stiffness` per spring, `mass` split evenly over the cage vertices).
    pub msd: MsdConfig,
    /// Spring layout.
    pub springs: CageSprings,
}

impl CageModelConfig {
    /// The paper's cage MSD parameters (stiffness 50 per spring, total mass 20, damping 0.3)
    /// at step `dt`, integrated with symplectic Euler: one force evaluation per step instead
    /// of RK4's four, stable at the paper's step with room to spare (the cage springs are
    /// soft), and substepped automatically if a stiffer cage needs it.
    /// [`CageModelConfig::paper_rk4`] is the paper's integrator.
    pub fn paper(dt: f64) -> Self {
        let mut msd = MsdConfig::paper(&PAPER_CAGE_MSD, dt);
        msd.integrator = MsdIntegrator::SymplecticEuler;
        CageModelConfig {
            msd,
            springs: CageSprings::Auto,
        }
    }

    /// The paper's cage MSD exactly: its parameters and RK4.
    pub fn paper_rk4(dt: f64) -> Self {
        CageModelConfig {
            msd: MsdConfig::paper(&PAPER_CAGE_MSD, dt),
            springs: CageSprings::Auto,
        }
    }
}

/// What the last cage step did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct CageStepStats {
    /// Substeps of the cage MSD.
    pub substeps: u32,
}

/// The springs of `layout` on `cage`.
fn cage_springs(cage: &Cage, layout: CageSprings, stiffness: f64) -> Vec<Spring> {
    let v = cage.vertices();
    let n = v.len();
    let layout = match layout {
        CageSprings::Auto if n <= 12 => CageSprings::Complete,
        CageSprings::Auto => CageSprings::EdgesBendingStruts,
        other => other,
    };
    let mut pairs: Vec<[u32; 2]> = Vec::new();
    match layout {
        CageSprings::Complete => {
            for a in 0..n as u32 {
                for b in a + 1..n as u32 {
                    pairs.push([a, b]);
                }
            }
        }
        _ => {
            pairs.extend(cage.edges());
            // Opposite vertices across every edge.
            let mut opposite: std::collections::HashMap<[u32; 2], Vec<u32>> = Default::default();
            for t in cage.triangles() {
                for k in 0..3 {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    opposite
                        .entry([a.min(b), a.max(b)])
                        .or_default()
                        .push(t[(k + 2) % 3]);
                }
            }
            for o in opposite.values() {
                if let [c, d] = o[..] {
                    pairs.push([c.min(d), c.max(d)]);
                }
            }
            // Struts along the inward vertex normals.
            let mut normals = vec![Vec3::zeros(); n];
            for t in cage.triangles() {
                let p = t.map(|i| v[i as usize]);
                let c = (p[1] - p[0]).cross(&(p[2] - p[0]));
                for &i in t {
                    normals[i as usize] += c;
                }
            }
            for i in 0..n {
                let inward = -normals[i];
                let far = (0..n).filter(|&j| j != i).max_by(|&a, &b| {
                    (v[a] - v[i])
                        .dot(&inward)
                        .total_cmp(&(v[b] - v[i]).dot(&inward))
                });
                if let Some(j) = far {
                    pairs.push([i.min(j) as u32, i.max(j) as u32]);
                }
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs
        .into_iter()
        .map(|[a, b]| Spring {
            a,
            b,
            stiffness,
            rest_length: (v[b as usize] - v[a as usize]).norm(),
        })
        .collect()
}

/// A body simulated at the cage level: the cage vertices run an MSD; the embedded points
/// (usually the body's surface vertices, or all its nodes) follow by Green coordinates.
#[derive(Debug)]
pub struct CageModel {
    pub(super) cage: Cage,
    pub(super) coords: Arc<GreenCoordinates>,
    pub(super) msd: MsdBody,
    face_terms: Vec<Vec3>,
    scratch: FastScratch,
    points: Vec<Vec3>,
    stats: CageStepStats,
    /// Calibrated dynamics: when set, steps use it instead of the cage MSD's springs (the
    /// MSD then only holds the cage state).
    pub(super) reduced: Option<ReducedStepper>,
    /// Contact workspaces.
    pub(super) contact: super::contact::CageContact,
    /// A displacement added to each embedded point (see [`CageModel::set_detail`]).
    detail: Option<Vec<Vec3>>,
    /// The buffer of a detail cleared, reused by the next one (a switch down sets one; the
    /// steps do not allocate once warm).
    detail_spare: Vec<Vec3>,
    /// A displacement of each point on top of the map and the detail (see
    /// [`CageModel::add_dent`]).
    dent: Option<Vec<Vec3>>,
    /// The buffer of a dent cleared, reused by the next one.
    dent_spare: Vec<Vec3>,
}

impl CageModel {
    /// A cage body embedding `points` (at rest) in `cage`. A point outside the cage is an
    /// error naming it.
    pub fn new(cage: Cage, points: &[Vec3], config: &CageModelConfig) -> Result<Self, CageError> {
        let coords = Arc::new(GreenCoordinates::new(&cage, points)?);
        CageModel::with_coordinates(cage, coords, config)
    }

    /// A cage body sharing precomputed coordinates (identical bodies can share one
    /// [`GreenCoordinates`]). The coordinates must have been computed for this cage.
    pub fn with_coordinates(
        cage: Cage,
        coords: Arc<GreenCoordinates>,
        config: &CageModelConfig,
    ) -> Result<Self, CageError> {
        CageModel::build(cage, coords, config, &Boundary::free())
    }

    /// A cage body whose cage vertices are held by `boundary` (fixed components, anchors),
    /// for example a cage resting on a support.
    pub fn with_boundary(
        cage: Cage,
        points: &[Vec3],
        config: &CageModelConfig,
        boundary: &Boundary,
    ) -> Result<Self, CageError> {
        let coords = Arc::new(GreenCoordinates::new(&cage, points)?);
        CageModel::build(cage, coords, config, boundary)
    }

    fn build(
        cage: Cage,
        coords: Arc<GreenCoordinates>,
        config: &CageModelConfig,
        boundary: &Boundary,
    ) -> Result<Self, CageError> {
        if coords.vertex_count() != cage.vertices().len()
            || coords.face_count() != cage.triangles().len()
        {
            return Err(CageError::LengthMismatch {
                what: "coordinates (cage vertices + faces)",
                expected: cage.vertices().len() + cage.triangles().len(),
                found: coords.vertex_count() + coords.face_count(),
            });
        }
        config.msd.validate()?;
        let n = cage.vertices().len();
        let springs = cage_springs(&cage, config.springs, config.msd.stiffness);
        let masses = vec![config.msd.mass / n as f64; n];
        let msd = MsdBody::new(
            cage.vertices().to_vec(),
            masses,
            springs,
            config.msd,
            boundary,
        )?;
        let mut body = CageModel {
            face_terms: vec![Vec3::zeros(); cage.triangles().len()],
            scratch: coords.scratch(),
            points: coords.rest_points().to_vec(),
            cage,
            coords,
            msd,
            stats: CageStepStats::default(),
            reduced: None,
            contact: Default::default(),
            detail: None,
            detail_spare: Vec::new(),
            dent: None,
            dent_spare: Vec::new(),
        };
        body.update_points()?;
        Ok(body)
    }

    /// The rest cage.
    pub fn cage(&self) -> &Cage {
        &self.cage
    }

    /// The coordinates (shareable).
    pub fn coordinates(&self) -> &Arc<GreenCoordinates> {
        &self.coords
    }

    /// The cage MSD (cage vertex positions, velocities, forces).
    pub fn msd(&self) -> &MsdBody {
        &self.msd
    }

    /// Mutable cage MSD. Call [`CageModel::update_points`] after moving cage vertices.
    pub fn msd_mut(&mut self) -> &mut MsdBody {
        &mut self.msd
    }

    /// Replaces the cage MSD's springs by calibrated dynamics (see
    /// [`crate::cage::ReducedModel`]) stepped at `dt`, or goes back to the springs (`None`).
    pub fn set_reduced(
        &mut self,
        model: Option<Arc<ReducedModel>>,
        dt: f64,
    ) -> Result<(), CageError> {
        self.reduced = match model {
            Some(m) => {
                if m.dim() != 3 * self.cage.vertices().len() {
                    return Err(CageError::LengthMismatch {
                        what: "reduced model coordinates (3 per cage vertex)",
                        expected: 3 * self.cage.vertices().len(),
                        found: m.dim(),
                    });
                }
                Some(ReducedStepper::new(m, dt)?)
            }
            None => None,
        };
        Ok(())
    }

    /// The calibrated dynamics, if the cage uses them.
    pub fn reduced(&self) -> Option<&Arc<ReducedModel>> {
        self.reduced.as_ref().map(|r| r.model())
    }

    /// Current cage vertex positions.
    pub fn cage_positions(&self) -> &[Vec3] {
        self.msd.positions()
    }

    /// The embedded points as of the last step or update (`f32`-accurate displacement).
    pub fn points(&self) -> &[Vec3] {
        &self.points
    }

    /// What the last step did.
    pub fn last_step(&self) -> CageStepStats {
        self.stats
    }

    /// Advances the cage MSD one step and re-evaluates the embedded points. On error the
    /// state is unchanged.
    pub fn step(&mut self) -> Result<CageStepStats, CageError> {
        if let Some(r) = self.reduced.as_mut() {
            let nodes = self.msd.nodes_mut();
            if let Some((what, index)) = nodes.first_non_finite_input() {
                return Err(CageError::NonFinite { what, index });
            }
            r.step(&mut nodes.x, &mut nodes.v, &mut nodes.f_ext)?;
            self.stats = CageStepStats { substeps: 1 };
        } else {
            let s = self.msd.step()?;
            self.stats = CageStepStats {
                substeps: s.substeps,
            };
        }
        self.update_points()?;
        Ok(self.stats)
    }

    /// Makes the current cage positions the equilibrium the cage returns to (`true`), or its
    /// rest shape again (`false`): the calibrated dynamics hold the displacement, the cage
    /// MSD's springs take the current lengths.
    pub fn rebase_equilibrium(&mut self, here: bool) {
        match self.reduced.as_mut() {
            Some(r) => r.rebase(here.then_some(self.msd.positions())),
            None => {
                if !here {
                    let rest = self.cage.vertices().to_vec();
                    let x = self.msd.positions().to_vec();
                    self.msd.positions_mut().copy_from_slice(&rest);
                    self.msd.rebase_rest();
                    self.msd.positions_mut().copy_from_slice(&x);
                } else {
                    self.msd.rebase_rest();
                }
            }
        }
    }

    /// Re-evaluates the embedded points from the current cage (fast path).
    pub fn update_points(&mut self) -> Result<(), CageError> {
        let x = self.msd.positions();
        self.coords.face_terms(x, &mut self.face_terms);
        self.coords
            .evaluate_fast(x, &self.face_terms, &mut self.scratch, &mut self.points)?;
        if let Some(d) = &self.detail {
            for (p, d) in self.points.iter_mut().zip(d) {
                *p += d;
            }
        }
        if let Some(d) = &self.dent {
            for (p, d) in self.points.iter_mut().zip(d) {
                *p += d;
            }
        }
        if let Some(index) = self
            .points
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(CageError::NonFinite {
                what: "point",
                index,
            });
        }
        Ok(())
    }

    /// The embedded points evaluated in `f64` (for state transfer and checks).
    pub fn exact_points(&mut self, out: &mut [Vec3]) -> Result<(), CageError> {
        let x = self.msd.positions();
        self.coords.face_terms(x, &mut self.face_terms);
        self.coords.evaluate(x, &self.face_terms, out)?;
        self.add_detail(out);
        Ok(())
    }

    /// Keeps a displacement of each embedded point on top of what the cage gives (`None`:
    /// none, the default): the shape a free body came to rest in on its supports, less what
    /// its cage reproduces, so the cage level holds that shape exactly. The length must be
    /// the number of points. Drops the dent (see [`CageModel::add_dent`]): a detail is set
    /// when the state is made anew (a down-switch, a reset).
    pub fn set_detail(&mut self, detail: Option<Vec<Vec3>>) -> Result<(), CageError> {
        if let Some(d) = &detail
            && d.len() != self.points.len()
        {
            return Err(CageError::LengthMismatch {
                what: "detail (one displacement per point)",
                expected: self.points.len(),
                found: d.len(),
            });
        }
        if let Some(old) = std::mem::replace(&mut self.detail, detail) {
            self.detail_spare = old;
        }
        self.clear_dent();
        self.update_points()
    }

    /// Adds `displacements` (one per point) to the dent: what a contact presses into the
    /// surface beyond what the cage's shapes show (see
    /// [`crate::precision::LeveledModel::contact_compliance`]), kept on top of the map and
    /// the detail until [`CageModel::clear_dent`]. Call [`CageModel::update_points`] after.
    /// Another length or a non-finite displacement is an error, and nothing is added.
    pub fn add_dent(&mut self, displacements: &[Vec3]) -> Result<(), CageError> {
        if displacements.len() != self.points.len() {
            return Err(CageError::LengthMismatch {
                what: "dent (one displacement per point)",
                expected: self.points.len(),
                found: displacements.len(),
            });
        }
        if let Some(index) = displacements
            .iter()
            .position(|d| !d.iter().all(|c| c.is_finite()))
        {
            return Err(CageError::NonFinite {
                what: "dent of point",
                index,
            });
        }
        let dent = self.dent.get_or_insert_with(|| {
            let mut d = std::mem::take(&mut self.dent_spare);
            d.clear();
            d.resize(displacements.len(), Vec3::zeros());
            d
        });
        for (d, a) in dent.iter_mut().zip(displacements) {
            *d += a;
        }
        Ok(())
    }

    /// The dent (see [`CageModel::add_dent`]); `None` without one.
    pub fn dent(&self) -> Option<&[Vec3]> {
        self.dent.as_deref()
    }

    /// Drops the dent (see [`CageModel::add_dent`]). Call [`CageModel::update_points`] after.
    pub fn clear_dent(&mut self) {
        if let Some(d) = self.dent.take() {
            self.dent_spare = d;
        }
    }

    /// Sets the detail to `exact - cage` point by point (the shape `exact` the cage's own
    /// points `cage` miss), reusing the last detail's buffer; drops the dent, as
    /// [`CageModel::set_detail`] does.
    pub fn set_detail_between(&mut self, exact: &[Vec3], cage: &[Vec3]) -> Result<(), CageError> {
        for (what, found) in [("exact points", exact.len()), ("cage points", cage.len())] {
            if found != self.points.len() {
                return Err(CageError::LengthMismatch {
                    what,
                    expected: self.points.len(),
                    found,
                });
            }
        }
        let mut d = self
            .detail
            .take()
            .unwrap_or_else(|| std::mem::take(&mut self.detail_spare));
        d.clear();
        d.extend(exact.iter().zip(cage).map(|(x, c)| x - c));
        self.detail = Some(d);
        self.clear_dent();
        self.update_points()
    }

    /// Adds the detail displacement (if any) and the dent to points evaluated from the
    /// cage.
    pub fn add_detail(&self, points: &mut [Vec3]) {
        if let Some(d) = &self.detail {
            for (p, d) in points.iter_mut().zip(d) {
                *p += d;
            }
        }
        if let Some(d) = &self.dent {
            for (p, d) in points.iter_mut().zip(d) {
                *p += d;
            }
        }
    }

    /// Applies a force at embedded point `point` for the next step: cage vertex `i` receives
    /// `phi_i f` (the transpose of the coordinates; the face terms are ignored, as in the
    /// paper), or with calibrated dynamics the transpose of the linearised map, face terms
    /// included. A point out of range is an error.
    pub fn apply_point_force(&mut self, point: usize, force: Vec3) -> Result<(), CageError> {
        if point >= self.coords.point_count() {
            return Err(CageError::InvalidArgument {
                field: "point",
                message: format!(
                    "{point} out of range ({} points)",
                    self.coords.point_count()
                ),
            });
        }
        if !force.iter().all(|c| c.is_finite()) {
            return Err(CageError::InvalidArgument {
                field: "force",
                message: format!("not finite: {:?}", [force.x, force.y, force.z]),
            });
        }
        if let Some(r) = self.reduced.as_ref() {
            // Calibrated dynamics: the whole transpose of the linearised map, face terms
            // included (the generalised force of the projection).
            let f = &mut self.msd.nodes_mut().f_ext;
            r.model()
                .add_point_force(self.coords.phi(point), self.coords.psi(point), force, f);
            return Ok(());
        }
        let f = self.msd.external_forces_mut();
        for (fi, phi) in f.iter_mut().zip(self.coords.phi(point)) {
            *fi += force * *phi;
        }
        Ok(())
    }

    /// Applies a force at any position inside the rest cage (coordinates computed on the
    /// fly; allocates). A position outside the cage is an error.
    pub fn apply_force_at(&mut self, rest_position: Vec3, force: Vec3) -> Result<(), CageError> {
        let (phi, _, w) = coordinates_at(&self.cage, &rest_position);
        if (w - 1.0).abs() > 1e-6 || phi.iter().any(|v| !v.is_finite()) {
            return Err(CageError::PointOutside {
                point: 0,
                position: [rest_position.x, rest_position.y, rest_position.z],
                winding: w,
            });
        }
        let f = self.msd.external_forces_mut();
        for (fi, phi) in f.iter_mut().zip(&phi) {
            *fi += force * *phi;
        }
        Ok(())
    }

    /// Moves the cage so the given embedded points move by the given displacements, in the
    /// least-squares sense with the smallest cage motion (`dV = Phi^T (Phi Phi^T)^-1 D`, the
    /// face terms held fixed), then re-evaluates the points. Velocities are kept.
    pub fn displace_points(&mut self, targets: &[(usize, Vec3)]) -> Result<(), CageError> {
        let n = self.coords.point_count();
        for &(p, d) in targets {
            if p >= n || !d.iter().all(|c| c.is_finite()) {
                return Err(CageError::InvalidArgument {
                    field: "targets",
                    message: format!("point {p} (of {n}) with displacement {:?}", [d.x, d.y, d.z]),
                });
            }
        }
        if targets.is_empty() {
            return Ok(());
        }
        let nv = self.coords.vertex_count();
        let m = targets.len();
        let phi = DMatrix::from_fn(m, nv, |r, c| self.coords.phi(targets[r].0)[c]);
        let mut gram = &phi * phi.transpose();
        // Tikhonov term relative to the diagonal: keeps repeated or near-identical points
        // solvable.
        let reg = 1e-10 * gram.diagonal().max();
        for i in 0..m {
            gram[(i, i)] += reg;
        }
        let chol = gram.cholesky().ok_or_else(|| CageError::InvalidArgument {
            field: "targets",
            message: "the points' coordinates are not independent".into(),
        })?;
        let x = self.msd.positions_mut();
        for a in 0..3 {
            let d = DVector::from_fn(m, |r, _| targets[r].1[a]);
            let y = chol.solve(&d);
            let dv = phi.transpose() * y;
            for (xi, dvi) in x.iter_mut().zip(dv.iter()) {
                xi[a] += dvi;
            }
        }
        self.update_points()
    }

    /// Moves the cage body rigidly by `m` (a teleport): its rest cage, coordinates and
    /// calibrated dynamics with the cage MSD's rest and anchors, so nothing springs back, and
    /// its state (vertex positions moved, velocities and pending forces turned), the detail
    /// and the embedded points. On error (the turned calibrated system cannot be factored)
    /// it is left as it was.
    pub(crate) fn move_by(&mut self, m: &nalgebra::Isometry3<f64>) -> Result<(), CageError> {
        let at = |p: &Vec3| m * nalgebra::Point3::from(*p) - nalgebra::Point3::origin();
        if let Some(r) = self.reduced.as_mut() {
            r.move_by(m)?;
        }
        for v in &mut self.cage.vertices {
            *v = at(v);
        }
        self.coords = Arc::new(self.coords.moved(m));
        let turned = m.rotation.angle() != 0.0;
        let nodes = self.msd.nodes_mut();
        nodes.move_rest(m);
        nodes.move_state(m);
        // The springs keep their lengths; a BDF2 history of differences turns with the body.
        if turned {
            self.msd.restart_history();
        }
        for p in &mut self.points {
            *p = at(p);
        }
        for d in self.detail.iter_mut().flatten() {
            *d = m.rotation * *d;
        }
        for d in self.dent.iter_mut().flatten() {
            *d = m.rotation * *d;
        }
        Ok(())
    }

    /// Puts the cage back at rest.
    pub fn reset(&mut self) -> Result<(), CageError> {
        self.msd.reset();
        self.clear_dent();
        self.update_points()
    }
}
