//! The precise solvers' hard cases, runnable by the tests (which check their outcome against
//! criteria) and by `soft-tissue report` (which tabulates it).
//!
//! Each case runs on a body held on its bottom 10 % (along y, gravity off): a disturbance
//! (a kick, a fold through itself, flattened elements, a tool force of many body weights on
//! one node for 1 s) and then free motion. The report records how it went: every step
//! succeeded or which failed, whether an explicit step was split into substeps or refused,
//! the energy when the disturbance ended and its peak afterwards, the distances from rest.

use crate::Vec3;
use crate::boundary::Boundary;
use crate::fem::{FemBody, FemConfig, FemError, FemIntegrator, FemModel, element};
use crate::material::{FemParams, MsdParams};
use crate::mesh::TetMesh;
use crate::msd::{ExplicitLimit, MsdBody, MsdConfig, MsdError, MsdIntegrator};
use crate::state::NodalModel;

/// How a case disturbs the body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Disturbance {
    /// This horizontal speed on the top 20 % of the nodes.
    Kick(f64),
    /// The top 25 % of the body folded down through the plane below it (inverts elements).
    Fold,
    /// Every 25th element above the fixed base flattened (zero volume).
    Squash,
    /// A horizontal force of this many body weights on one top node for 1 s, then released.
    ToolForce(f64),
}

/// The solver of a case.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CaseMethod {
    /// FEM, implicit Euler.
    Fem(FemModel),
    /// FEM, BDF2 (second order).
    FemBdf2(FemModel),
    /// Mass-spring-damper with this integrator.
    Msd(MsdIntegrator),
}

/// The time step of a case.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CaseStep {
    /// This multiple of the parameters' own step.
    Times(f64),
    /// This multiple of the explicit MSD's stability limit.
    LimitTimes(f64),
}

/// One hard case.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HardCase {
    /// What it tests.
    pub name: &'static str,
    /// Solver.
    pub method: CaseMethod,
    /// Young's modulus (FEM) or spring stiffness (MSD) times this.
    pub stiffness_scale: f64,
    /// Poisson ratio override (FEM).
    pub poisson: Option<f64>,
    /// Time step.
    pub step: CaseStep,
    /// Volume springs of the MSD (0: edges only, as in the paper).
    pub volume_stiffness: f64,
    /// The disturbance.
    pub disturbance: Disturbance,
    /// What an explicit MSD does above its stability limit.
    pub explicit_limit: ExplicitLimit,
}

/// Volume stiffness of the MSD cases that invert elements: edge springs alone cannot tell a
/// tetrahedron from its mirror image, so without it a folded MSD body stays folded.
pub const FOLD_VOLUME_STIFFNESS: f64 = 2000.0;

impl HardCase {
    fn new(name: &'static str, method: CaseMethod, disturbance: Disturbance) -> Self {
        HardCase {
            name,
            method,
            stiffness_scale: 1.0,
            poisson: None,
            step: CaseStep::Times(1.0),
            volume_stiffness: 0.0,
            disturbance,
            explicit_limit: ExplicitLimit::Substep { max_substeps: 1000 },
        }
    }

    /// The solvers issue's hard cases: for both FEM models Poisson 0.49, Young x1000 and
    /// ten times the step under a kick, initially inverted and flattened elements, a tool
    /// force of 100 body weights, each with backward Euler and (linear, corotational) with
    /// BDF2; for the MSD stiff
    /// springs x1000 (implicit Euler and BDF2), the tool force, flattened and folded bodies
    /// (RK4, implicit Euler and BDF2), and RK4 at three times its stability limit,
    /// substepped and refused.
    pub fn all() -> Vec<HardCase> {
        let mut v = Vec::new();
        let models = [
            FemModel::Linear,
            FemModel::Corotational,
            FemModel::CorotationalPrefactored,
        ];
        // BDF2 for the models that take it (not the prefactored one).
        let fem = models.map(CaseMethod::Fem).into_iter().chain([
            CaseMethod::FemBdf2(FemModel::Linear),
            CaseMethod::FemBdf2(FemModel::Corotational),
        ]);
        for f in fem {
            v.push(HardCase {
                poisson: Some(0.49),
                ..HardCase::new("Poisson 0.49", f, Disturbance::Kick(2.0))
            });
            v.push(HardCase {
                stiffness_scale: 1000.0,
                ..HardCase::new("Young x1000", f, Disturbance::Kick(2.0))
            });
            v.push(HardCase {
                step: CaseStep::Times(10.0),
                ..HardCase::new("dt x10", f, Disturbance::Kick(2.0))
            });
            v.push(HardCase {
                poisson: Some(0.3),
                ..HardCase::new("initially inverted", f, Disturbance::Fold)
            });
            v.push(HardCase {
                poisson: Some(0.3),
                ..HardCase::new("initially flat", f, Disturbance::Squash)
            });
            v.push(HardCase::new(
                "tool force 100x weight",
                f,
                Disturbance::ToolForce(100.0),
            ));
        }
        let implicit = CaseMethod::Msd(MsdIntegrator::ImplicitEuler);
        let bdf2 = CaseMethod::Msd(MsdIntegrator::ImplicitBdf2);
        let rk4 = CaseMethod::Msd(MsdIntegrator::Rk4);
        for m in [implicit, bdf2] {
            v.push(HardCase {
                stiffness_scale: 1000.0,
                ..HardCase::new("stiffness x1000", m, Disturbance::Kick(2.0))
            });
        }
        for m in [rk4, implicit, bdf2] {
            v.push(HardCase::new(
                "tool force 100x weight",
                m,
                Disturbance::ToolForce(100.0),
            ));
            v.push(HardCase::new("initially flat", m, Disturbance::Squash));
            v.push(HardCase {
                volume_stiffness: FOLD_VOLUME_STIFFNESS,
                ..HardCase::new("initially inverted", m, Disturbance::Fold)
            });
        }
        v.push(HardCase {
            step: CaseStep::LimitTimes(3.0),
            explicit_limit: ExplicitLimit::Substep { max_substeps: 16 },
            ..HardCase::new("dt 3x its limit, substep", rk4, Disturbance::Kick(2.0))
        });
        v.push(HardCase {
            step: CaseStep::LimitTimes(3.0),
            explicit_limit: ExplicitLimit::Refuse,
            ..HardCase::new("dt 3x its limit, refuse", rk4, Disturbance::Kick(2.0))
        });
        v
    }

    /// Short solver name.
    pub fn method_name(&self) -> &'static str {
        match self.method {
            CaseMethod::Fem(FemModel::Linear) => "FEM linear",
            CaseMethod::Fem(FemModel::Corotational) => "FEM corotational",
            CaseMethod::Fem(FemModel::CorotationalPrefactored) => "FEM corotational prefactored",
            CaseMethod::FemBdf2(FemModel::Linear) => "FEM linear BDF2",
            CaseMethod::FemBdf2(FemModel::Corotational) => "FEM corotational BDF2",
            CaseMethod::FemBdf2(FemModel::CorotationalPrefactored) => {
                "FEM corotational prefactored BDF2"
            }
            CaseMethod::Msd(MsdIntegrator::Rk4) => "MSD RK4",
            CaseMethod::Msd(MsdIntegrator::SymplecticEuler) => "MSD symplectic",
            CaseMethod::Msd(MsdIntegrator::ImplicitEuler) => "MSD implicit",
            CaseMethod::Msd(MsdIntegrator::ImplicitBdf2) => "MSD BDF2",
        }
    }
}

/// How a case ended.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// Every step ran at the requested step.
    Stable,
    /// Every step ran, split into this many substeps (explicit MSD above its limit).
    Substepped(u32),
    /// The first step was refused with this error (explicit MSD above its limit).
    Refused(String),
    /// A step failed or the state stopped being finite.
    Failed {
        /// Step index.
        step: usize,
        /// What went wrong.
        message: String,
    },
}

/// What a case measured.
#[derive(Debug, Clone, PartialEq)]
pub struct CaseReport {
    /// The case.
    pub case: HardCase,
    /// Time step used, seconds.
    pub dt: f64,
    /// Steps run.
    pub steps: usize,
    /// How it ended.
    pub outcome: Outcome,
    /// Elements inverted and flat right after the disturbance.
    pub inverted: usize,
    /// See `inverted`.
    pub flat: usize,
    /// Energy (kinetic + elastic) when the disturbance ended.
    pub end_energy: f64,
    /// Largest energy from then on.
    pub peak_energy: f64,
    /// Largest node distance from rest when the disturbance ended, fraction of the width.
    pub disturbed_distance: f64,
    /// Largest node distance from rest after the last step, fraction of the width.
    pub final_distance: f64,
    /// Largest node speed after the last step, widths per second.
    pub final_speed: f64,
}

/// Building a case's body failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StabilityError {
    /// FEM body.
    #[error("{case}: {source}")]
    Fem {
        /// Case name and solver.
        case: String,
        /// Cause.
        source: FemError,
    },
    /// MSD body.
    #[error("{case}: {source}")]
    Msd {
        /// Case name and solver.
        case: String,
        /// Cause.
        source: MsdError,
    },
}

enum Body {
    Fem(Box<FemBody>),
    Msd(Box<MsdBody>),
}

impl Body {
    fn nodal(&self) -> &dyn NodalModel {
        match self {
            Body::Fem(b) => b.as_ref(),
            Body::Msd(b) => b.as_ref(),
        }
    }
    fn nodal_mut(&mut self) -> &mut dyn NodalModel {
        match self {
            Body::Fem(b) => b.as_mut(),
            Body::Msd(b) => b.as_mut(),
        }
    }
    fn energy(&self) -> f64 {
        match self {
            Body::Fem(b) => b.kinetic_energy() + b.elastic_energy(),
            Body::Msd(b) => b.kinetic_energy() + b.elastic_energy(),
        }
    }
    /// Steps; returns the substeps taken.
    fn step(&mut self) -> Result<u32, String> {
        match self {
            Body::Fem(b) => b.step().map(|_| 1).map_err(|e| e.to_string()),
            Body::Msd(b) => b.step().map(|s| s.substeps).map_err(|e| e.to_string()),
        }
    }
}

fn width(mesh: &TetMesh) -> f64 {
    let b = mesh.bbox();
    (b.max.x - b.min.x).min(b.max.z - b.min.z)
}

fn top_nodes(mesh: &TetMesh, fraction: f64) -> Vec<usize> {
    let b = mesh.bbox();
    let cut = b.max.y - fraction * (b.max.y - b.min.y);
    (0..mesh.positions().len())
        .filter(|&i| mesh.positions()[i].y >= cut)
        .collect()
}

fn disturb_positions(mesh: &TetMesh, d: Disturbance, x: &mut [Vec3]) {
    let b = mesh.bbox();
    let h = b.max.y - b.min.y;
    match d {
        Disturbance::Fold => {
            let cut = b.max.y - 0.25 * h;
            for p in x.iter_mut() {
                if p.y > cut {
                    p.y = 2.0 * cut - p.y;
                }
            }
        }
        Disturbance::Squash => {
            // Later moves may partly undo earlier ones; the report counts what is flat.
            let floor = b.min.y + 0.15 * h;
            for tet in mesh.tets().iter().step_by(25) {
                let [a, b, c, d] = tet.map(|i| i as usize);
                if mesh.positions()[d].y < floor {
                    continue;
                }
                let n = (x[b] - x[a]).cross(&(x[c] - x[a]));
                let len = n.norm();
                if len > 0.0 {
                    let n = n / len;
                    let off = (x[d] - x[a]).dot(&n);
                    x[d] -= off * n;
                }
            }
        }
        Disturbance::Kick(_) | Disturbance::ToolForce(_) => {}
    }
}

/// Counts inverted and (nearly) flat elements of positions `x`.
pub fn inverted_and_flat(mesh: &TetMesh, x: &[Vec3]) -> (usize, usize) {
    let (mut inv, mut flat) = (0, 0);
    for (t, vol0) in mesh.tets().iter().zip(mesh.tet_volumes()) {
        let p = t.map(|i| x[i as usize]);
        let v = element::shape_gradients(&p).map(|(_, v)| v).unwrap_or(0.0);
        if v.abs() <= 1e-9 * vol0 {
            flat += 1;
        } else if v < 0.0 {
            inv += 1;
        }
    }
    (inv, flat)
}

fn distance(mesh: &TetMesh, x: &[Vec3]) -> f64 {
    x.iter()
        .zip(mesh.positions())
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max)
}

/// Runs `case` for `steps` steps on `mesh` (held on its bottom 10 % along y) with the FEM
/// material `fem` at step `fem_dt` or the MSD parameters `msd` at step `msd_dt`.
pub fn run_case(
    mesh: &TetMesh,
    case: &HardCase,
    (fem, fem_dt): (&FemParams, f64),
    (msd, msd_dt): (&MsdParams, f64),
    steps: usize,
) -> Result<CaseReport, StabilityError> {
    let label = format!("{} ({})", case.name, case.method_name());
    let boundary = Boundary::fixed_below(mesh.positions(), 1, 0.1);
    let mut body = match case.method {
        CaseMethod::Fem(model) | CaseMethod::FemBdf2(model) => {
            let dt = match case.step {
                CaseStep::Times(s) | CaseStep::LimitTimes(s) => fem_dt * s,
            };
            let mut c = FemConfig::paper(fem, dt);
            c.model = model;
            if let CaseMethod::FemBdf2(_) = case.method {
                c.integrator = FemIntegrator::Bdf2;
            }
            c.young_modulus *= case.stiffness_scale;
            if let Some(nu) = case.poisson {
                c.poisson_ratio = nu;
            }
            let b = FemBody::new(mesh, c, &boundary).map_err(|source| StabilityError::Fem {
                case: label.clone(),
                source,
            })?;
            Body::Fem(Box::new(b))
        }
        CaseMethod::Msd(integrator) => {
            let err = |source| StabilityError::Msd {
                case: label.clone(),
                source,
            };
            let mut c = MsdConfig::paper(msd, msd_dt);
            c.integrator = integrator;
            c.stiffness *= case.stiffness_scale;
            c.volume_stiffness = case.volume_stiffness;
            c.explicit_limit = case.explicit_limit;
            c.dt = match case.step {
                CaseStep::Times(s) => msd_dt * s,
                CaseStep::LimitTimes(s) => {
                    let probe = MsdBody::from_mesh(mesh, c, &boundary).map_err(err)?;
                    s * probe.stable_dt()
                }
            };
            Body::Msd(Box::new(
                MsdBody::from_mesh(mesh, c, &boundary).map_err(err)?,
            ))
        }
    };
    let dt = match &body {
        Body::Fem(b) => b.config().dt,
        Body::Msd(b) => b.config().dt,
    };
    let w = width(mesh);
    let top = top_nodes(mesh, 0.2);
    let node = top_nodes(mesh, 0.05).first().copied().unwrap_or(0);
    match case.disturbance {
        Disturbance::Kick(speed) => {
            for &i in &top {
                body.nodal_mut().velocities_mut()[i] = Vec3::new(speed, 0.0, 0.5 * speed);
            }
        }
        Disturbance::Fold | Disturbance::Squash => {
            disturb_positions(mesh, case.disturbance, body.nodal_mut().positions_mut());
        }
        Disturbance::ToolForce(_) => {}
    }
    let (inverted, flat) = inverted_and_flat(mesh, body.nodal().positions());
    let active = match case.disturbance {
        Disturbance::ToolForce(_) => (1.0 / dt).round() as usize,
        _ => 0,
    };
    let weight = body.nodal().masses().iter().sum::<f64>() * 9.81;
    let mut end_energy = body.energy();
    let mut peak_energy = end_energy;
    let mut disturbed_distance = distance(mesh, body.nodal().positions()) / w;
    let mut most_substeps = 1;
    let mut outcome = None;
    let mut ran = 0;
    for s in 0..steps {
        if let Disturbance::ToolForce(times) = case.disturbance
            && s < active
        {
            body.nodal_mut()
                .add_force(node, Vec3::new(times * weight, 0.0, 0.0));
        }
        match body.step() {
            Ok(sub) => most_substeps = most_substeps.max(sub),
            Err(message) => {
                outcome = Some(if s == 0 && message.contains("stability limit") {
                    Outcome::Refused(message)
                } else {
                    Outcome::Failed { step: s, message }
                });
                break;
            }
        }
        ran = s + 1;
        let e = body.energy();
        if !e.is_finite() {
            outcome = Some(Outcome::Failed {
                step: s,
                message: format!("energy {e}"),
            });
            break;
        }
        if s + 1 == active {
            end_energy = e;
            peak_energy = e;
            disturbed_distance = distance(mesh, body.nodal().positions()) / w;
        }
        if s >= active {
            peak_energy = peak_energy.max(e);
        }
    }
    let outcome = outcome.unwrap_or(if most_substeps > 1 {
        Outcome::Substepped(most_substeps)
    } else {
        Outcome::Stable
    });
    Ok(CaseReport {
        case: *case,
        dt,
        steps: ran,
        outcome,
        inverted,
        flat,
        end_energy,
        peak_energy,
        disturbed_distance,
        final_distance: distance(mesh, body.nodal().positions()) / w,
        final_speed: body.nodal().max_speed() / w,
    })
}
