//! Heat conduction in the tissue and the thermal damage it causes.
//!
//! Per-node temperature on the tetrahedral mesh (P1 finite elements on the rest shape, so the
//! field does not care which mechanical level the body is at), lumped heat capacity
//! `C_i = rho c V_i` (a quarter of each adjacent tetrahedron's volume), conductivity matrix
//! `K_ij = sum_e k V_e grad N_i . grad N_j`, and implicit (backward) Euler:
//!
//! ```text
//! (C + dt K) T' = C T + dt Q
//! ```
//!
//! The matrix is constant: it is factorized once at construction (sparse Cholesky) and each step
//! is one allocation-free solve. With insulated boundaries the rows of `K` sum to zero, so the
//! stored heat `sum_i C_i T_i` changes by exactly `dt sum_i Q_i` per step (energy is conserved
//! up to round-off, whatever the step size). Fixed-temperature nodes (Dirichlet) are eliminated.
//!
//! Damage is the Arrhenius integral `Omega = int A exp(-Ea / (R T)) dt` per node (T in kelvin),
//! accumulated only while the node is above a threshold temperature (by default 43 C, below
//! which tissue takes hours to be harmed and the Arrhenius rate at body temperature would
//! otherwise add a slow spurious drift). `1 - exp(-Omega)` is the damaged fraction; `Omega = 1`
//! (63 %) is the usual coagulation boundary.
//!
//! Lengths: the mesh is in scene units, the heat parameters in SI. `meters_per_unit` converts
//! (the paper's organs are about 2 units long; a real liver is about 0.2 m).

use serde::{Deserialize, Serialize};

pub mod closed_form;
mod electrode;
mod spot;

pub use spot::{
    BurnVolumes, CELLS as SPOT_SHELLS, ELECTRODE_RADIUS_RANGE, ElectrodeSource, MAX_SUBSTEPS,
    MIN_OUTER_RADIUS, RETIRE_KELVIN, SpotPlace,
};
use spot::{RadialGrid, Spot};

use std::sync::Arc;

use crate::Vec3;
use crate::fem::element::shape_gradients;
use crate::linalg::{LinalgError, ScalarCholesky};
use crate::mesh::TetMesh;

/// Universal gas constant, J / (mol K).
pub const GAS_CONSTANT: f64 = 8.314_462_618;
/// 0 C in kelvin.
pub const KELVIN_OFFSET: f64 = 273.15;

const POSITIVE: &str = "finite and > 0";
const ABOVE_ZERO: &str = "finite and above absolute zero";
const NON_NEGATIVE: &str = "finite and >= 0";

/// A parameter check: field, value, the test it must pass, what is expected.
type Rule = (&'static str, f64, fn(f64) -> bool, &'static str);

/// Thermal parameters of a tissue (SI units, temperatures in degrees Celsius).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub struct HeatParams {
    /// Thermal conductivity, W / (m K).
    pub conductivity: f64,
    /// Density, kg / m^3.
    pub density: f64,
    /// Specific heat capacity, J / (kg K).
    pub specific_heat: f64,
    /// Initial (body) temperature, C.
    pub initial_temperature: f64,
    /// Arrhenius frequency factor A, 1 / s.
    pub damage_frequency: f64,
    /// Arrhenius activation energy Ea, J / mol.
    pub damage_activation_energy: f64,
    /// No damage accumulates at or below this temperature, C.
    pub damage_threshold: f64,
    /// Metres per mesh (scene) unit.
    pub meters_per_unit: f64,
    /// Pennes blood perfusion (none by default).
    #[serde(default)]
    pub perfusion: Perfusion,
    /// Water and its boiling, for electrodes that vaporize tissue.
    #[serde(default)]
    pub vaporization: Vaporization,
}

/// Pennes blood perfusion: `-w rho_b c_b (T - T_a)` per unit volume.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub struct Perfusion {
    /// Blood perfusion rate w, m^3 of blood per m^3 of tissue per second (0: none).
    pub rate: f64,
    /// Blood density, kg/m^3.
    pub blood_density: f64,
    /// Blood specific heat, J/(kg K).
    pub blood_specific_heat: f64,
    /// Arterial blood temperature, C.
    pub arterial_temperature: f64,
}

impl Perfusion {
    /// No perfusion.
    pub fn none() -> Self {
        Perfusion {
            rate: 0.0,
            ..Self::liver()
        }
    }

    /// Liver: w = 6.4e-3 1/s, the value used in radio-frequency ablation models of liver
    /// (e.g. Chang and Nguyen 2004, cited at [`HeatParams::liver`]); blood 1060 kg/m^3 and
    /// 3617 J/(kg K) (IT'IS database); arterial blood at 37 C.
    pub fn liver() -> Self {
        Perfusion {
            rate: 6.4e-3,
            blood_density: 1060.0,
            blood_specific_heat: 3617.0,
            arterial_temperature: 37.0,
        }
    }

    /// `w rho_b c_b`, W/(m^3 K).
    pub fn coefficient(&self) -> f64 {
        self.rate * self.blood_density * self.blood_specific_heat
    }

    /// Perfusion length `sqrt(k / (w rho_b c_b))` for conductivity `k`, m (infinite
    /// without perfusion).
    pub fn length(&self, conductivity: f64) -> f64 {
        (conductivity / self.coefficient()).sqrt()
    }
}

impl Default for Perfusion {
    fn default() -> Self {
        Self::none()
    }
}

/// The tissue's water, which boils at an electrode before the tissue vaporizes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub struct Vaporization {
    /// Mass fraction of water (liver: about 0.78, IT'IS database).
    pub water_fraction: f64,
    /// Latent heat of vaporization of water at 100 C, J/kg (2.257e6).
    pub latent_heat: f64,
    /// Boiling temperature, C (100 at one atmosphere).
    pub boiling_temperature: f64,
}

impl Default for Vaporization {
    fn default() -> Self {
        Vaporization {
            water_fraction: 0.78,
            latent_heat: 2.257e6,
            boiling_temperature: 100.0,
        }
    }
}

impl HeatParams {
    /// Liver: conductivity 0.52 W/(m K), density 1079 kg/m^3, specific heat 3540 J/(kg K)
    /// (IT'IS Foundation tissue properties database, liver), body temperature 37 C; Arrhenius
    /// A = 7.39e39 1/s, Ea = 2.577e5 J/mol, the liver coagulation values commonly used in
    /// radio-frequency ablation models (e.g. Chang and Nguyen, BioMedical Engineering OnLine
    /// 3:27, 2004). `meters_per_unit` is 0.1 (the paper's 2-unit organs become 0.2 m).
    pub fn liver() -> Self {
        HeatParams {
            conductivity: 0.52,
            density: 1079.0,
            specific_heat: 3540.0,
            initial_temperature: 37.0,
            damage_frequency: 7.39e39,
            damage_activation_energy: 2.577e5,
            damage_threshold: 43.0,
            meters_per_unit: 0.1,
            perfusion: Perfusion::none(),
            vaporization: Vaporization::default(),
        }
    }

    /// Thermal diffusivity `k / (rho c)`, m^2 / s.
    pub fn diffusivity(&self) -> f64 {
        self.conductivity / (self.density * self.specific_heat)
    }

    /// Checks every field; the error names it.
    pub fn validate(&self) -> Result<(), HeatError> {
        let (p, v) = (&self.perfusion, &self.vaporization);
        let above_zero = |t: f64| t.is_finite() && t > -KELVIN_OFFSET;
        let positive = |x: f64| x.is_finite() && x > 0.0;
        let non_negative = |x: f64| x.is_finite() && x >= 0.0;
        let rules: [Rule; 15] = [
            ("conductivity", self.conductivity, positive, POSITIVE),
            ("density", self.density, positive, POSITIVE),
            ("specific_heat", self.specific_heat, positive, POSITIVE),
            ("meters_per_unit", self.meters_per_unit, positive, POSITIVE),
            (
                "damage_activation_energy",
                self.damage_activation_energy,
                positive,
                POSITIVE,
            ),
            (
                "initial_temperature",
                self.initial_temperature,
                above_zero,
                ABOVE_ZERO,
            ),
            (
                "damage_threshold",
                self.damage_threshold,
                above_zero,
                ABOVE_ZERO,
            ),
            (
                "damage_frequency",
                self.damage_frequency,
                non_negative,
                NON_NEGATIVE,
            ),
            ("perfusion.rate", p.rate, non_negative, NON_NEGATIVE),
            (
                "perfusion.blood_density",
                p.blood_density,
                positive,
                POSITIVE,
            ),
            (
                "perfusion.blood_specific_heat",
                p.blood_specific_heat,
                positive,
                POSITIVE,
            ),
            (
                "perfusion.arterial_temperature",
                p.arterial_temperature,
                above_zero,
                ABOVE_ZERO,
            ),
            (
                "vaporization.latent_heat",
                v.latent_heat,
                positive,
                POSITIVE,
            ),
            // Dry tissue at an electrode would heat without bound.
            (
                "vaporization.water_fraction",
                v.water_fraction,
                |x| x > 0.0 && x <= 1.0,
                "in (0, 1]",
            ),
            (
                "vaporization.boiling_temperature",
                v.boiling_temperature,
                above_zero,
                ABOVE_ZERO,
            ),
        ];
        for (field, value, ok, expected) in rules {
            if !ok(value) {
                return Err(HeatError::BadParameter {
                    field,
                    value,
                    expected,
                });
            }
        }
        Ok(())
    }
}

impl Default for HeatParams {
    fn default() -> Self {
        Self::liver()
    }
}

/// Boundary conditions of the heat problem.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct HeatBoundary {
    /// Nodes held at a temperature (C). Every other node is insulated (zero flux).
    pub fixed: Vec<(usize, f64)>,
}

impl HeatBoundary {
    /// Every boundary insulated.
    pub fn insulated() -> Self {
        Self::default()
    }
}

/// A failure of the heat model, naming what and where.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HeatError {
    /// A parameter is out of range.
    #[error("heat parameter `{field}` = {value} must be {expected}")]
    BadParameter {
        /// Field name.
        field: &'static str,
        /// Value given.
        value: f64,
        /// What is expected.
        expected: &'static str,
    },
    /// The step is not positive and finite.
    #[error("heat time step {0} must be finite and > 0")]
    BadTimeStep(f64),
    /// A node index is out of range.
    #[error("heat: node {node} out of range (mesh has {nodes} nodes)")]
    BadNode {
        /// Node given.
        node: usize,
        /// Nodes of the mesh.
        nodes: usize,
    },
    /// A fixed temperature or a source power is not finite.
    #[error("heat: {what} at node {node} is not finite ({value})")]
    NonFinite {
        /// Which input.
        what: &'static str,
        /// Node.
        node: usize,
        /// Value given.
        value: f64,
    },
    /// A tetrahedron is degenerate (zero volume), so it has no temperature gradient.
    #[error("heat: tetrahedron {tet} is degenerate")]
    DegenerateTet {
        /// Tetrahedron index.
        tet: usize,
    },
    /// The linear solve failed; `dof` is the node.
    #[error("heat: linear algebra failed at node {node}: {source}")]
    Linalg {
        /// Node of the failure.
        node: usize,
        /// Underlying error.
        source: LinalgError,
    },
    /// The step produced a non-finite temperature (left the field unchanged).
    #[error("heat: step produced a non-finite temperature at node {node}; state left unchanged")]
    Diverged {
        /// First node with a non-finite value.
        node: usize,
    },
}

fn linalg(e: LinalgError) -> HeatError {
    let node = match &e {
        LinalgError::NotPositiveDefinite { dof } | LinalgError::NonFinite { dof } => *dof,
        _ => 0,
    };
    HeatError::Linalg { node, source: e }
}

/// The temperature and damage fields of one body (see the module docs).
#[derive(Debug)]
pub struct HeatField {
    params: HeatParams,
    dt: f64,
    temperature: Vec<f64>,
    damage: Vec<f64>,
    capacity: Vec<f64>,
    /// Whether the last step changed a temperature or a damage integral.
    changed: bool,
    /// Counts the changes of the temperatures or damage (steps that changed them, resets).
    version: u64,
    fixed: Vec<Option<f64>>,
    /// `(free node i, fixed node j, dt K_ij)`: the coupling of free rows to fixed values.
    coupling: Vec<(u32, u32, f64)>,
    factor: ScalarCholesky,
    power: Vec<f64>,
    rhs: Vec<f64>,
    time: f64,
    /// Rest position of every node, scene units (where a spot's heat goes when it ends).
    positions: Vec<Vec3>,
    /// Perfusion conductance to arterial blood per node, W/K (empty without perfusion).
    perfusion: Vec<f64>,
    /// The electrodes' sub-grid fields, oldest first.
    spots: Vec<Spot>,
    grids: Vec<Arc<RadialGrid>>,
    /// Burnt volumes of spots that ended, m^3, and the heat their water took with the
    /// sensible heat of their vaporized tissue (both left as steam), J.
    retired: BurnVolumes,
    retired_boiled: f64,
    /// What ended spots burnt, and those of the field before a change of the mesh (newest
    /// last, at most [`MAX_MARKS`]): where new samples start.
    marks: Vec<spot::BurnMark>,
    /// Heat that left with changes of the mesh, J (see [`HeatField::departed_heat`]).
    departed: f64,
    samples: Vec<HeatSample>,
    sample_temperature: Vec<f64>,
    sample_damage: Vec<f64>,
    sample_peak: Vec<f64>,
}

/// A point where temperature and damage are followed at the sub-grid scale (a vertex of a
/// rendered surface): its rest position (scene units) and the coarse nodes and weights that
/// interpolate the coarse field there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeatSample {
    /// Rest position, scene units.
    pub position: Vec3,
    /// Coarse nodes and weights (summing to 1).
    pub nodes: [(u32, f64); 4],
}

/// Spots a field keeps at once; a new one ends the oldest without power.
pub const MAX_SPOTS: usize = 32;

/// Most burn marks a field keeps (what ended spots burnt; see
/// [`HeatField::set_samples`]).
pub const MAX_MARKS: usize = 64;

impl HeatField {
    /// Builds the field on the rest shape of `mesh` at the initial temperature, factorizes the
    /// step matrix for `dt` seconds.
    pub fn new(
        mesh: &TetMesh,
        params: HeatParams,
        dt: f64,
        boundary: &HeatBoundary,
    ) -> Result<Self, HeatError> {
        params.validate()?;
        if !(dt.is_finite() && dt > 0.0) {
            return Err(HeatError::BadTimeStep(dt));
        }
        let n = mesh.node_count();
        let mut fixed = vec![None; n];
        for &(node, t) in &boundary.fixed {
            if node >= n {
                return Err(HeatError::BadNode { node, nodes: n });
            }
            if !t.is_finite() || t <= -KELVIN_OFFSET {
                return Err(HeatError::NonFinite {
                    what: "fixed temperature",
                    node,
                    value: t,
                });
            }
            fixed[node] = Some(t);
        }
        let s = params.meters_per_unit;
        let mut capacity = vec![0.0; n];
        let mut entries = Vec::with_capacity(16 * mesh.tet_count());
        let positions = mesh.positions();
        for (e, tet) in mesh.tets().iter().enumerate() {
            let x: [Vec3; 4] = std::array::from_fn(|a| positions[tet[a] as usize]);
            let (g, volume) = shape_gradients(&x).ok_or(HeatError::DegenerateTet { tet: e })?;
            // In SI: V s^3 and gradients / s, so K_e = k V s (g_a . g_b).
            let ke = params.conductivity * volume * s;
            let ce = params.density * params.specific_heat * volume * s * s * s / 4.0;
            for a in 0..4 {
                let i = tet[a] as usize;
                capacity[i] += ce;
                for b in 0..4 {
                    entries.push((i, tet[b] as usize, ke * g[a].dot(&g[b])));
                }
            }
        }
        // Nodes no tetrahedron uses (real meshes have them) conduct nothing; a capacity keeps
        // the matrix definite and their temperature constant.
        let smallest = capacity
            .iter()
            .copied()
            .filter(|&c| c > 0.0)
            .fold(f64::INFINITY, f64::min);
        for c in &mut capacity {
            if *c <= 0.0 && smallest.is_finite() {
                *c = smallest;
            }
        }
        let mut coupling = Vec::new();
        let mut matrix = Vec::with_capacity(entries.len() + n);
        for &(i, j, k) in &entries {
            match (fixed[i], fixed[j]) {
                (None, Some(_)) => coupling.push((i as u32, j as u32, dt * k)),
                (None, None) => matrix.push((i, j, dt * k)),
                _ => {}
            }
        }
        // Pennes perfusion: a conductance to arterial blood, lumped like the capacity.
        let coefficient = params.perfusion.coefficient();
        let perfusion: Vec<f64> = if coefficient > 0.0 {
            let rho_c = params.density * params.specific_heat;
            capacity.iter().map(|c| coefficient * c / rho_c).collect()
        } else {
            Vec::new()
        };
        for (i, &c) in capacity.iter().enumerate() {
            let w = perfusion.get(i).map_or(0.0, |w| dt * w);
            matrix.push((i, i, c + w));
        }
        let is_fixed: Vec<bool> = fixed.iter().map(Option::is_some).collect();
        let factor = ScalarCholesky::new(n, matrix, &is_fixed).map_err(linalg)?;
        let temperature = fixed
            .iter()
            .map(|f| f.unwrap_or(params.initial_temperature))
            .collect();
        Ok(HeatField {
            params,
            dt,
            temperature,
            damage: vec![0.0; n],
            capacity,
            fixed,
            coupling,
            factor,
            power: vec![0.0; n],
            rhs: vec![0.0; n],
            time: 0.0,
            changed: false,
            version: 0,
            positions: mesh.positions().to_vec(),
            perfusion,
            spots: Vec::new(),
            grids: Vec::new(),
            retired: BurnVolumes::default(),
            retired_boiled: 0.0,
            marks: Vec::new(),
            departed: 0.0,
            samples: Vec::new(),
            sample_temperature: Vec::new(),
            sample_damage: Vec::new(),
            sample_peak: Vec::new(),
        })
    }

    /// Parameters.
    pub fn params(&self) -> &HeatParams {
        &self.params
    }

    /// Step, s.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// Simulated time, s.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Temperature per node, C.
    pub fn temperatures(&self) -> &[f64] {
        &self.temperature
    }

    /// Sets every free node's temperature (fixed nodes keep theirs). For initial conditions.
    pub fn set_temperatures(&mut self, f: impl Fn(usize) -> f64) -> Result<(), HeatError> {
        for i in 0..self.temperature.len() {
            if self.fixed[i].is_none() {
                let t = f(i);
                if !t.is_finite() {
                    return Err(HeatError::NonFinite {
                        what: "temperature",
                        node: i,
                        value: t,
                    });
                }
                self.temperature[i] = t;
            }
        }
        Ok(())
    }

    /// Sets every node's damage integral (a field carried over from another mesh, say a
    /// body before a cut); each must be finite (below zero counts as zero).
    pub fn set_damage(&mut self, f: impl Fn(usize) -> f64) -> Result<(), HeatError> {
        for i in 0..self.damage.len() {
            let d = f(i);
            if !d.is_finite() {
                return Err(HeatError::NonFinite {
                    what: "damage",
                    node: i,
                    value: d,
                });
            }
            self.damage[i] = d.max(0.0);
        }
        self.changed = true;
        self.version += 1;
        Ok(())
    }

    /// Arrhenius damage integral per node (dimensionless).
    pub fn damage(&self) -> &[f64] {
        &self.damage
    }

    /// Damaged fraction `1 - exp(-Omega)` of node `i`, in [0, 1].
    pub fn damaged_fraction(&self, i: usize) -> f64 {
        1.0 - (-self.damage[i]).exp()
    }

    /// Heat capacity per node, J / K.
    pub fn capacities(&self) -> &[f64] {
        &self.capacity
    }

    /// Stored heat relative to 0 C, `sum C_i T_i`, plus what the electrodes' spots hold
    /// (their excess and the heat their water took, also of spots that ended), J.
    pub fn heat_content(&self) -> f64 {
        self.coarse_heat_content() + self.subgrid_heat_content()
    }

    /// Heat that left the body's field with changes of its mesh, J: the coarse field's heat
    /// of tissue an electrode's crater carved out, and what handing the field to a cut mesh
    /// changed (the spots' heat given to the nodes where they do not go on, new nodes'
    /// capacities; a carve that leaves one piece keeps the spots), counted on the piece that
    /// kept the body. Summed over the body's pieces, `heat_content` plus this is what the
    /// sources delivered since the start, across cuts and carves.
    pub fn departed_heat(&self) -> f64 {
        self.departed
    }

    /// Notes that `joules` more left with a change of the mesh.
    pub(crate) fn add_departed(&mut self, joules: f64) {
        self.departed += joules;
    }

    /// The coarse field's part of [`HeatField::heat_content`], J.
    pub fn coarse_heat_content(&self) -> f64 {
        self.capacity
            .iter()
            .zip(&self.temperature)
            .map(|(c, t)| c * t)
            .sum()
    }

    /// The sub-grid part of [`HeatField::heat_content`], J.
    pub fn subgrid_heat_content(&self) -> f64 {
        self.spots.iter().map(Spot::energy).sum::<f64>() + self.retired_boiled
    }

    /// Adds `watts` of heating at `node` for the next step (negative cools).
    pub fn add_power(&mut self, node: usize, watts: f64) -> Result<(), HeatError> {
        let n = self.power.len();
        if node >= n {
            return Err(HeatError::BadNode { node, nodes: n });
        }
        if !watts.is_finite() {
            return Err(HeatError::NonFinite {
                what: "power",
                node,
                value: watts,
            });
        }
        self.power[node] += watts;
        Ok(())
    }

    /// Whether the last step changed any temperature or damage (a field at equilibrium with
    /// no source does not: readers can skip it).
    pub fn changed(&self) -> bool {
        self.changed
    }

    /// A number that changes whenever the temperatures or the damage do (a step that changed
    /// them, a reset): a reader that kept the last one it saw knows whether to read again.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Power queued for the next step, W.
    pub fn queued_power(&self) -> f64 {
        self.power.iter().sum()
    }

    /// One implicit Euler step of `dt`, then damage accumulation; clears the queued power. On
    /// error the temperatures are unchanged.
    pub fn step(&mut self) -> Result<(), HeatError> {
        self.solve_next()?;
        self.commit();
        Ok(())
    }

    /// Solves the next step's temperatures without taking them (see
    /// [`HeatField::commit`]): a caller whose other part of the step failed can drop them,
    /// leaving the field as it was.
    pub fn solve_next(&mut self) -> Result<(), HeatError> {
        let dt = self.dt;
        for (i, r) in self.rhs.iter_mut().enumerate() {
            *r = match self.fixed[i] {
                Some(t) => t,
                None => self.capacity[i] * self.temperature[i] + dt * self.power[i],
            };
        }
        if !self.perfusion.is_empty() {
            let arterial = self.params.perfusion.arterial_temperature;
            for (i, w) in self.perfusion.iter().enumerate() {
                if self.fixed[i].is_none() {
                    self.rhs[i] += dt * w * arterial;
                }
            }
        }
        // The spots step first; what crosses their outer radius enters the coarse field in
        // this step. Each over its shells' bases now (the coarse field and the other spots'
        // excess of the last step; each spot's buffer, reused: no allocation), which its
        // boiling and then its damage take.
        for k in 0..self.spots.len() {
            let mut base = std::mem::take(&mut self.spots[k].next_base);
            self.shell_bases(k, &mut base);
            self.spots[k].next_base = base;
        }
        for k in 0..self.spots.len() {
            let spot = &mut self.spots[k];
            spot.solve(&self.params);
            for &(node, w) in &spot.nodes {
                if self.fixed[node as usize].is_none() {
                    self.rhs[node as usize] += w * spot.outflow;
                }
            }
        }
        for &(i, j, k) in &self.coupling {
            let tj = self.fixed[j as usize].unwrap_or(0.0);
            self.rhs[i as usize] -= k * tj;
        }
        self.factor.solve_in_place(&mut self.rhs).map_err(linalg)?;
        if let Some(node) = self.rhs.iter().position(|t| !t.is_finite()) {
            return Err(HeatError::Diverged { node });
        }
        Ok(())
    }

    /// Takes the temperatures [`HeatField::solve_next`] solved: damage, time and version
    /// advance, the queued power is spent.
    pub fn commit(&mut self) {
        let dt = self.dt;
        self.changed = self.rhs != self.temperature;
        self.temperature.copy_from_slice(&self.rhs);
        self.power.fill(0.0);
        let p = &self.params;
        if p.damage_frequency > 0.0 {
            for (omega, &t) in self.damage.iter_mut().zip(&self.temperature) {
                if t > p.damage_threshold {
                    self.changed = true;
                    let kelvin = t + KELVIN_OFFSET;
                    let rate = p.damage_frequency
                        * (-p.damage_activation_energy / (GAS_CONSTANT * kelvin)).exp();
                    *omega += dt * rate;
                }
            }
        }
        self.time += dt;
        self.commit_spots();
        self.update_samples();
        if self.changed {
            self.version += 1;
        }
    }

    /// Back to the initial temperature with no damage and no queued power.
    pub fn reset(&mut self) {
        for (t, f) in self.temperature.iter_mut().zip(&self.fixed) {
            *t = f.unwrap_or(self.params.initial_temperature);
        }
        self.damage.fill(0.0);
        self.power.fill(0.0);
        self.spots.clear();
        self.retired = BurnVolumes::default();
        self.retired_boiled = 0.0;
        self.marks.clear();
        self.departed = 0.0;
        self.sample_damage.fill(0.0);
        self.sample_peak.fill(self.params.initial_temperature);
        for k in 0..self.samples.len() {
            self.sample_temperature[k] = interpolate(&self.temperature, &self.samples[k].nodes);
        }
        self.time = 0.0;
        self.changed = true;
        self.version += 1;
    }
}

fn interpolate(t: &[f64], nodes: &[(u32, f64)]) -> f64 {
    nodes.iter().map(|&(n, w)| w * t[n as usize]).sum()
}
