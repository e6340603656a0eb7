//! A benchmark load for the precise solvers, shared by `soft-tissue bench` and the criterion
//! benches: the body is held on its bottom 10 % (fixed, y up) while a horizontal force on its
//! top 5 % nodes swings back and forth with a period of 1 s, so every step deforms the body
//! instead of timing a body at rest. The force amplitude is `E a^2 / 50` (FEM) or
//! `k a / 5` (MSD), with `a` the smallest bounding-box side, which bends the paper's bodies by
//! a few percent of their size, like a tool pressing on them. Gravity is optional (the paper's
//! cylinders scene has it, the organs scene does not).
//!
//! Cage methods run the same swinging force on the top 5 % of the surface vertices, mapped
//! onto a box or fitted cage (cage vertices in the bottom 10 % fixed) with the paper's cage MSD
//! at its `dt` of 0.02; a step is the cage MSD step plus the Green-coordinate evaluation of
//! every surface vertex.

use std::str::FromStr;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::Vec3;
use crate::boundary::Boundary;
use crate::cage::{CageError, CageModel, CageModelConfig, FitOptions, box_cage, fitted_cage};
use crate::fem::{FemBody, FemConfig, FemError, FemIntegrator, FemModel};
use crate::material::{FemParams, MsdParams};
use crate::mesh::TetMesh;
use crate::msd::{MsdBody, MsdConfig, MsdError, MsdIntegrator};
use crate::state::NodalModel;
use crate::timing::TimeStats;

/// A precise method to benchmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum BenchMethod {
    /// Linear FEM, implicit Euler, prefactored.
    FemLinear,
    /// Corotational FEM, implicit Euler, warm-started PCG.
    FemCorotational,
    /// Corotational FEM with a constant, prefactored, rotation-invariant system.
    FemCorotationalPrefactored,
    /// MSD with RK4 (the paper).
    MsdRk4,
    /// MSD with symplectic Euler.
    MsdSymplectic,
    /// MSD with linearised implicit Euler.
    MsdImplicit,
    /// The cage level with the paper's bounding-box cage.
    CageBox,
    /// The cage level with a fitted cage (vertex budget set by the caller, 64 by default).
    CageFitted,
}

impl BenchMethod {
    /// Every method.
    pub const ALL: [BenchMethod; 8] = [
        BenchMethod::FemLinear,
        BenchMethod::FemCorotational,
        BenchMethod::FemCorotationalPrefactored,
        BenchMethod::MsdRk4,
        BenchMethod::MsdSymplectic,
        BenchMethod::MsdImplicit,
        BenchMethod::CageBox,
        BenchMethod::CageFitted,
    ];

    /// Whether this is a cage-level method.
    pub fn is_cage(self) -> bool {
        matches!(self, BenchMethod::CageBox | BenchMethod::CageFitted)
    }

    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            BenchMethod::FemLinear => "fem-linear",
            BenchMethod::FemCorotational => "fem-corotational",
            BenchMethod::FemCorotationalPrefactored => "fem-corotational-prefactored",
            BenchMethod::MsdRk4 => "msd-rk4",
            BenchMethod::MsdSymplectic => "msd-symplectic",
            BenchMethod::MsdImplicit => "msd-implicit",
            BenchMethod::CageBox => "cage-box",
            BenchMethod::CageFitted => "cage-fitted",
        }
    }
}

impl FromStr for BenchMethod {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        BenchMethod::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                let names: Vec<_> = BenchMethod::ALL.iter().map(|m| m.name()).collect();
                format!("unknown method '{s}': expected one of {}", names.join(", "))
            })
    }
}

/// A solver failure during a benchmark.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BenchError {
    /// FEM error.
    #[error(transparent)]
    Fem(#[from] FemError),
    /// MSD error.
    #[error(transparent)]
    Msd(#[from] MsdError),
    /// Cage error.
    #[error(transparent)]
    Cage(#[from] CageError),
}

enum Solver {
    Fem(Box<FemBody>),
    Msd(Box<MsdBody>),
    Cage(Box<CageModel>),
}

/// A body under the benchmark load.
pub struct BenchBody {
    solver: Solver,
    top: Vec<usize>,
    amplitude: f64,
    dt: f64,
    time: f64,
    cg_iterations: u64,
    substeps: u64,
    steps: u64,
    /// FEM stage times of the timed steps: forces, assembly, solve.
    stage_times: [Vec<f64>; 3],
    timing: bool,
}

/// Timings of a benchmark run, in microseconds per step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchReport {
    /// Method name.
    pub method: String,
    /// Mesh nodes.
    pub nodes: usize,
    /// Mesh tetrahedra.
    pub tets: usize,
    /// Timed steps.
    pub steps: usize,
    /// Time step of the method, time units.
    pub dt: f64,
    /// Fastest step.
    pub min_us: f64,
    /// Median step.
    pub median_us: f64,
    /// Mean step.
    pub mean_us: f64,
    /// 99th percentile.
    pub p99_us: f64,
    /// Slowest step.
    pub max_us: f64,
    /// Mean CG iterations per step (implicit methods).
    pub mean_cg_iterations: f64,
    /// Mean substeps per step (explicit MSD).
    pub mean_substeps: f64,
    /// Largest node displacement from rest over the timed steps, as a fraction of the
    /// smallest bounding-box side (shows the load deforms the body, and by how much).
    pub max_displacement_ratio: f64,
    /// Cage methods: cage vertices (0 otherwise).
    pub cage_vertices: usize,
    /// Cage methods: embedded points evaluated per step, the surface vertices (0 otherwise).
    pub points: usize,
    /// The whole step: median, 99th percentile, largest (nearest rank).
    pub step: TimeStats,
    /// The stages of a step where the method has them (FEM: `forces`, the element loop;
    /// `assembly`, the warped stiffness, zero on steps that keep it; `solve`, the linear
    /// solve); empty otherwise.
    pub stages: Vec<(String, TimeStats)>,
}

impl BenchBody {
    /// Builds `method` on `mesh` with the given FEM / MSD parameters and time steps;
    /// `cage_vertices` is the budget of the fitted cage.
    pub fn new(
        mesh: &TetMesh,
        method: BenchMethod,
        fem: (&FemParams, f64),
        msd: (&MsdParams, f64),
        gravity: bool,
        cage_vertices: usize,
    ) -> Result<Self, BenchError> {
        let boundary = Boundary::fixed_below(mesh.positions(), 1, 0.1);
        let gravity = if gravity {
            Vec3::new(0.0, -9.81, 0.0)
        } else {
            Vec3::zeros()
        };
        let size = {
            let b = mesh.bbox();
            let d = b.max - b.min;
            d.x.min(d.y).min(d.z)
        };
        let (lo, hi) = {
            let b = mesh.bbox();
            (b.min.y, b.max.y)
        };
        let top: Vec<usize> = (0..mesh.positions().len())
            .filter(|&i| mesh.positions()[i].y >= hi - 0.05 * (hi - lo))
            .collect();
        let (solver, dt, total_force) = match method {
            BenchMethod::FemLinear
            | BenchMethod::FemCorotational
            | BenchMethod::FemCorotationalPrefactored => {
                let mut c = FemConfig::paper(fem.0, fem.1);
                c.gravity = gravity;
                c.model = match method {
                    BenchMethod::FemLinear => FemModel::Linear,
                    BenchMethod::FemCorotational => FemModel::Corotational,
                    _ => FemModel::CorotationalPrefactored,
                };
                let body = FemBody::new(mesh, c, &boundary)?;
                let force = fem.0.young_modulus * size * size / 50.0;
                (Solver::Fem(Box::new(body)), fem.1, force)
            }
            BenchMethod::CageBox | BenchMethod::CageFitted => {
                let nodes = mesh.positions();
                let options = FitOptions::for_points(nodes, cage_vertices);
                let cage = if method == BenchMethod::CageBox {
                    box_cage(nodes, options.margin)?
                } else {
                    fitted_cage(nodes, mesh.surface().triangles(), &options)?
                };
                let surface: Vec<Vec3> = mesh
                    .surface()
                    .vertices()
                    .iter()
                    .map(|&i| nodes[i as usize])
                    .collect();
                let mut config = CageModelConfig::paper(0.02);
                config.msd.gravity = gravity;
                let cage_boundary = Boundary::fixed_below(cage.vertices(), 1, 0.1);
                let body = CageModel::with_boundary(cage, &surface, &config, &cage_boundary)?;
                let force = config.msd.stiffness * size / 5.0;
                (Solver::Cage(Box::new(body)), config.msd.dt, force)
            }
            _ => {
                let mut c = MsdConfig::paper(msd.0, msd.1);
                c.gravity = gravity;
                c.integrator = match method {
                    BenchMethod::MsdRk4 => MsdIntegrator::Rk4,
                    BenchMethod::MsdSymplectic => MsdIntegrator::SymplecticEuler,
                    _ => MsdIntegrator::ImplicitEuler,
                };
                let body = MsdBody::from_mesh(mesh, c, &boundary)?;
                let force = msd.0.stiffness * size / 5.0;
                (Solver::Msd(Box::new(body)), msd.1, force)
            }
        };
        let top = match &solver {
            // Cage bodies load surface vertices (indices into the embedded points).
            Solver::Cage(_) => mesh
                .surface()
                .vertices()
                .iter()
                .enumerate()
                .filter(|(_, n)| top.contains(&(**n as usize)))
                .map(|(k, _)| k)
                .collect(),
            _ => top,
        };
        let amplitude = total_force / top.len().max(1) as f64;
        Ok(BenchBody {
            solver,
            top,
            amplitude,
            dt,
            time: 0.0,
            cg_iterations: 0,
            substeps: 0,
            steps: 0,
            stage_times: Default::default(),
            timing: false,
        })
    }

    /// Applies the load and advances one step.
    pub fn step(&mut self) -> Result<(), BenchError> {
        let phase = (2.0 * std::f64::consts::PI * self.time).sin();
        let force = Vec3::new(self.amplitude * phase, 0.0, 0.5 * self.amplitude * phase);
        match &mut self.solver {
            Solver::Fem(b) => {
                for &i in &self.top {
                    b.add_force(i, force);
                }
                let s = b.step()?;
                self.cg_iterations += s.cg.iterations as u64;
                self.substeps += 1;
                if self.timing {
                    for (v, t) in
                        self.stage_times
                            .iter_mut()
                            .zip([s.forces_us, s.assembly_us, s.solve_us])
                    {
                        v.push(t);
                    }
                }
            }
            Solver::Msd(b) => {
                for &i in &self.top {
                    b.add_force(i, force);
                }
                let s = b.step()?;
                self.cg_iterations += s.cg.iterations as u64;
                self.substeps += s.substeps as u64;
            }
            Solver::Cage(b) => {
                for &i in &self.top {
                    b.apply_point_force(i, force)?;
                }
                let s = b.step()?;
                self.substeps += s.substeps as u64;
            }
        }
        self.steps += 1;
        self.time += self.dt;
        Ok(())
    }

    /// Sets the CG tolerance and iteration cap of the implicit methods (corotational FEM,
    /// implicit MSD); no effect on the others.
    pub fn set_cg(&mut self, tolerance: f64, max_iterations: u32) -> Result<(), BenchError> {
        match &mut self.solver {
            Solver::Fem(b) => b.set_cg(tolerance, max_iterations)?,
            Solver::Msd(b) => b.set_cg(tolerance, max_iterations)?,
            Solver::Cage(_) => {}
        }
        Ok(())
    }

    /// Second-order time integration: BDF2 for the FEM methods ([`FemIntegrator::Bdf2`]),
    /// implicit MSD switched to [`MsdIntegrator::ImplicitBdf2`]; no effect on the explicit
    /// MSD and the cages.
    pub fn set_bdf2(&mut self, on: bool) -> Result<(), BenchError> {
        match &mut self.solver {
            Solver::Fem(b) => b.set_integrator(if on {
                FemIntegrator::Bdf2
            } else {
                FemIntegrator::BackwardEuler
            })?,
            Solver::Msd(b) if b.config().integrator.is_implicit() => b.set_integrator(if on {
                MsdIntegrator::ImplicitBdf2
            } else {
                MsdIntegrator::ImplicitEuler
            })?,
            Solver::Msd(_) | Solver::Cage(_) => {}
        }
        Ok(())
    }

    /// Sets [`FemConfig::rotation_tolerance`] of the FEM methods; no effect on the others.
    pub fn set_rotation_tolerance(&mut self, tolerance: f64) -> Result<(), BenchError> {
        if let Solver::Fem(b) = &mut self.solver {
            b.set_rotation_tolerance(tolerance)?;
        }
        Ok(())
    }

    /// Largest node displacement from rest.
    pub fn max_displacement(&self) -> f64 {
        let (x, x0) = match &self.solver {
            Solver::Fem(b) => (b.positions(), b.rest_positions()),
            Solver::Msd(b) => (b.positions(), b.rest_positions()),
            Solver::Cage(b) => (b.points(), b.coordinates().rest_points()),
        };
        x.iter()
            .zip(x0)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max)
    }

    /// Bytes of the FEM body's matrices and factors for the model in use (values and
    /// indices; see [`FemBody::matrix_bytes`]); `None` for the other methods.
    pub fn matrix_bytes(&self) -> Option<usize> {
        match &self.solver {
            Solver::Fem(b) => Some(b.matrix_bytes()),
            _ => None,
        }
    }

    /// Runs `warmup` untimed steps, then times `steps` steps one by one.
    pub fn run(
        &mut self,
        method: BenchMethod,
        mesh: &TetMesh,
        warmup: usize,
        steps: usize,
    ) -> Result<BenchReport, BenchError> {
        for _ in 0..warmup {
            self.step()?;
        }
        self.cg_iterations = 0;
        self.substeps = 0;
        self.steps = 0;
        // Room for the samples up front (a huge count grows as it goes instead).
        let room = steps.min(1 << 22);
        let mut times = Vec::with_capacity(room);
        for v in &mut self.stage_times {
            v.clear();
            v.reserve(room);
        }
        self.timing = true;
        let mut displacement: f64 = 0.0;
        for s in 0..steps {
            let t = Instant::now();
            let stepped = self.step();
            times.push(t.elapsed().as_secs_f64() * 1e6);
            if let Err(e) = stepped {
                self.timing = false;
                return Err(e);
            }
            if s % 10 == 0 {
                displacement = displacement.max(self.max_displacement());
            }
        }
        self.timing = false;
        let size = {
            let b = mesh.bbox();
            let d = b.max - b.min;
            d.x.min(d.y).min(d.z)
        };
        let step = TimeStats::of_sorted_in_place(&mut times);
        let stages = if self.stage_times[0].is_empty() {
            Vec::new()
        } else {
            ["forces", "assembly", "solve"]
                .iter()
                .zip(&mut self.stage_times)
                .map(|(name, v)| (name.to_string(), TimeStats::of_sorted_in_place(v)))
                .collect()
        };
        let n = steps.max(1) as f64;
        Ok(BenchReport {
            method: method.name().into(),
            nodes: mesh.positions().len(),
            tets: mesh.tets().len(),
            steps,
            dt: self.dt,
            min_us: step.min_us,
            median_us: step.median_us,
            mean_us: step.mean_us,
            p99_us: step.p99_us,
            max_us: step.max_us,
            mean_cg_iterations: self.cg_iterations as f64 / n,
            mean_substeps: self.substeps as f64 / n,
            max_displacement_ratio: displacement / size,
            cage_vertices: match &self.solver {
                Solver::Cage(b) => b.cage().vertices().len(),
                _ => 0,
            },
            points: match &self.solver {
                Solver::Cage(b) => b.points().len(),
                _ => 0,
            },
            step,
            stages,
        })
    }
}
