//! The sub-grid field of an electrode: heat at the millimetre scale the coarse mesh cannot
//! hold.
//!
//! An electrode of radius `a` pressed on the tissue puts its power into a few cubic
//! millimetres; a node of an organ mesh stands for centimetres. So each place an electrode
//! heats gets a *spot*: a spherically symmetric finite-volume model of the temperature excess
//! `u(r)` over the coarse field, on `CELLS` shells from `a` to an outer radius `R` (20 mm, or
//! ten electrode radii if larger) whose widths grow geometrically (0.05 mm at a 1 mm
//! electrode), stepped by implicit Euler in substeps of at most 2 ms with its tridiagonal
//! matrix factorized once:
//!
//! ```text
//! rho c du/dt = k (u'' + 2 u' / r) - w rho_b c_b u,   -k u'(a) = P / (4 pi a^2 f),   u(R) = 0
//! ```
//!
//! `f` is the share of the sphere around the electrode that is tissue (1/2 for an electrode
//! centred on a flat surface: by images, the field of a half-sunk electrode at an insulated
//! surface is that of the whole sphere at twice the power). Everything the model holds or
//! passes is counted at `f` times the whole sphere. The heat that crosses `R` goes to the
//! coarse field at the spot's nodes in the same step, so the coarse field takes the far part
//! and the energy of the two together is the energy delivered, to round-off. The temperature
//! anywhere is the coarse field's plus the excess of every spot within `R`.
//!
//! Above the boiling temperature a shell's water boils first (the temperature-recovery
//! method: the heat above boiling goes into latent heat until the shell's water, its water
//! fraction times its mass times the latent heat, is spent); a shell whose water is spent is
//! vaporized. Damage is the Arrhenius integral per shell.
//!
//! A shell's temperature is its excess over a base of its own: the coarse field around the
//! spot at that radius and the other spots' excess averaged over the shell's sphere. Taken at
//! the centre for every shell instead, the heat beside the centre stood for the spot's whole
//! 20 mm sphere: a spot started 1 mm from another electrode's (at boiling there), or on a
//! crater's floor whose small nodes took the heat of the spot carved out, coagulated and
//! charred all its shells at once, tens of cubic centimetres from joules.

use std::sync::Arc;

use super::{GAS_CONSTANT, HeatParams, KELVIN_OFFSET};
use crate::Vec3;

/// Shells of a spot.
pub const CELLS: usize = 64;
/// The longest substep of a spot, s.
pub const SUBSTEP: f64 = 2e-3;
/// Smallest outer radius of a spot, m.
pub const MIN_OUTER_RADIUS: f64 = 0.02;
/// Most substeps of a spot in one step (a step over 20 s takes longer substeps).
pub const MAX_SUBSTEPS: usize = 10_000;
/// Electrode radii a spot models, m.
pub const ELECTRODE_RADIUS_RANGE: std::ops::RangeInclusive<f64> = 1e-5..=0.05;
/// A spot with no power whose largest excess is below this, K, hands its heat to the coarse
/// field and ends.
pub const RETIRE_KELVIN: f64 = 0.05;

/// The shells of a spot for one electrode radius, material and step, with the step matrix
/// factorized (the Thomas algorithm's multipliers).
#[derive(Debug)]
pub(crate) struct RadialGrid {
    pub(crate) radius: f64,
    pub(crate) outer: f64,
    /// Node radius of each shell, m.
    r: Vec<f64>,
    /// Ratio of consecutive face radii.
    ratio: f64,
    /// Shell volume (whole sphere), m^3.
    pub(crate) volume: Vec<f64>,
    /// Heat capacity (whole sphere), J/K.
    capacity: Vec<f64>,
    /// Conductance from shell i to i+1 (the last: to the outer boundary), W/K.
    conductance: Vec<f64>,
    /// Heat to boil each shell's water (whole sphere), J.
    latent: Vec<f64>,
    substeps: usize,
    h: f64,
    /// Thomas algorithm: the pivots' reciprocals and the modified upper diagonal.
    pivot_inv: Vec<f64>,
    upper: Vec<f64>,
    lower: Vec<f64>,
}

impl RadialGrid {
    pub(crate) fn new(radius: f64, params: &HeatParams, dt: f64) -> Self {
        let outer = (10.0 * radius).max(MIN_OUTER_RADIUS);
        let ratio = (outer / radius).powf(1.0 / CELLS as f64);
        let face: Vec<f64> = (0..=CELLS)
            .map(|j| {
                if j == CELLS {
                    outer
                } else {
                    radius * ratio.powi(j as i32)
                }
            })
            .collect();
        let r: Vec<f64> = (0..CELLS).map(|i| 0.5 * (face[i] + face[i + 1])).collect();
        let pi = std::f64::consts::PI;
        let volume: Vec<f64> = (0..CELLS)
            .map(|i| 4.0 / 3.0 * pi * (face[i + 1].powi(3) - face[i].powi(3)))
            .collect();
        let rho_c = params.density * params.specific_heat;
        let capacity: Vec<f64> = volume.iter().map(|v| rho_c * v).collect();
        let k = params.conductivity;
        let conductance: Vec<f64> = (0..CELLS)
            .map(|i| {
                let next = if i + 1 < CELLS { r[i + 1] } else { outer };
                k * 4.0 * pi * face[i + 1] * face[i + 1] / (next - r[i])
            })
            .collect();
        let v = &params.vaporization;
        let latent: Vec<f64> = volume
            .iter()
            .map(|vol| v.water_fraction * params.density * vol * v.latent_heat)
            .collect();
        let substeps = (dt / SUBSTEP).ceil().clamp(1.0, MAX_SUBSTEPS as f64) as usize;
        let h = dt / substeps as f64;
        let perfusion = params.perfusion.coefficient();
        // A_ii = C_i / h + W_i + G_{i-1} + G_i, A_{i,i+1} = -G_i, A_{i,i-1} = -G_{i-1}.
        let mut pivot_inv = vec![0.0; CELLS];
        let mut upper = vec![0.0; CELLS];
        let mut lower = vec![0.0; CELLS];
        for i in 0..CELLS {
            let left = if i > 0 { conductance[i - 1] } else { 0.0 };
            let diag = capacity[i] / h + perfusion * volume[i] + left + conductance[i];
            lower[i] = -left;
            let pivot = if i > 0 {
                diag - lower[i] * upper[i - 1]
            } else {
                diag
            };
            pivot_inv[i] = 1.0 / pivot;
            upper[i] = if i + 1 < CELLS {
                -conductance[i] / pivot
            } else {
                0.0
            };
        }
        RadialGrid {
            radius,
            outer,
            r,
            ratio,
            volume,
            capacity,
            conductance,
            latent,
            substeps,
            h,
            pivot_inv,
            upper,
            lower,
        }
    }

    /// Node radius of each shell, m.
    pub(crate) fn shell_radii(&self) -> &[f64] {
        &self.r
    }

    /// The excess at distance `d` (m) from the centre, read from the shells' values `u`
    /// (linear between shell nodes, to zero at the outer radius, flat inside the first node).
    fn excess(&self, u: &[f64], d: f64) -> f64 {
        if d >= self.outer {
            return 0.0;
        }
        if d <= self.r[0] {
            return u[0];
        }
        let i = self.piece(d);
        let (r0, u0, r1, u1) = self.ends(u, i);
        u0 + (u1 - u0) * (d - r0) / (r1 - r0)
    }

    /// The linear piece of an excess that holds `d` (past the first shell node, inside the
    /// outer radius): from shell node `i` to the next (or to the outer radius).
    fn piece(&self, d: f64) -> usize {
        // The shell whose face interval holds d, then its node's neighbours.
        let j = ((d / self.radius).ln() / self.ratio.ln()).floor();
        let i = (j.max(0.0) as usize).min(CELLS - 1);
        if d < self.r[i] && i > 0 { i - 1 } else { i }
    }

    /// Piece `i`'s ends of the excess `u`: radii and values.
    fn ends(&self, u: &[f64], i: usize) -> (f64, f64, f64, f64) {
        if i + 1 < CELLS {
            (self.r[i], u[i], self.r[i + 1], u[i + 1])
        } else {
            (self.r[i], u[i], self.outer, 0.0)
        }
    }

    /// `int_0^d t u(t) dt` of the excess `u` (as [`RadialGrid::excess`] reads it), with
    /// `moments` its values at the shell nodes and the outer radius
    /// ([`Spot::update_moments`]), m^2 K.
    fn moment(&self, u: &[f64], moments: &[f64], d: f64) -> f64 {
        if d <= self.r[0] {
            return 0.5 * u[0] * d * d;
        }
        if d >= self.outer {
            return moments[CELLS];
        }
        let i = self.piece(d);
        let (r0, u0, r1, u1) = self.ends(u, i);
        moments[i] + piece_moment(r0, u0, r1, u1, d)
    }
}

/// `int_r0^d t u(t) dt` where `u` goes linearly from `u0` at `r0` to `u1` at `r1`.
fn piece_moment(r0: f64, u0: f64, r1: f64, u1: f64, d: f64) -> f64 {
    let b = (u1 - u0) / (r1 - r0);
    let a = u0 - b * r0;
    0.5 * a * (d * d - r0 * r0) + b * (d * d * d - r0 * r0 * r0) / 3.0
}

/// Where an electrode heats, this step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ElectrodeSource {
    /// The contact's centre on the rest mesh, scene units.
    pub center: Vec3,
    /// Power into the tissue, W.
    pub watts: f64,
    /// Electrode radius, m.
    pub radius: f64,
    /// Share of the sphere around the electrode that is tissue, in (0, 1] (1/2 on a flat
    /// surface). A source that joins a spot already at its place heats with that spot's
    /// fraction (the one it was made with).
    pub tissue_fraction: f64,
}

/// Electrode `electrode`'s mark in a spot's set of the electrodes that power it (electrodes
/// 64 apart in number share one).
pub(crate) fn electrode_bit(electrode: u32) -> u64 {
    1 << (electrode % 64)
}

/// Where a spot heats: its centre (rest, scene units), the coarse nodes and weights that
/// stand for it, and its tissue fraction (see [`crate::heat::HeatField::powered_spot`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SpotPlace {
    /// Centre, rest, scene units.
    pub center: Vec3,
    /// Coarse nodes and weights (summing to 1).
    pub nodes: Vec<(usize, f64)>,
    /// Share of the sphere about it that is tissue.
    pub tissue_fraction: f64,
}

/// Volumes of burnt tissue, m^3.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BurnVolumes {
    /// Damage integral at least 1 (63 % of the cells dead): coagulated.
    pub coagulated: f64,
    /// Reached the boiling temperature: desiccated and charred.
    pub charred: f64,
    /// Its water boiled away.
    pub vaporized: f64,
}

impl std::ops::AddAssign for BurnVolumes {
    fn add_assign(&mut self, o: Self) {
        self.coagulated += o.coagulated;
        self.charred += o.charred;
        self.vaporized += o.vaporized;
    }
}

/// One place an electrode heated (see the module docs).
#[derive(Debug, Clone)]
pub(crate) struct Spot {
    pub(crate) center: Vec3,
    /// The coarse nodes at the centre and their weights.
    pub(crate) nodes: Vec<(u32, f64)>,
    pub(crate) fraction: f64,
    pub(crate) grid: Arc<RadialGrid>,
    /// The coarse nodes around it (see [`Spot::coarse_bases`]).
    near: Vec<NearNode>,
    /// Each shell's base temperature (the coarse field there and the other spots' excess),
    /// C, of the last step, and the next step's (set before its solve).
    base: Vec<f64>,
    pub(crate) next_base: Vec<f64>,
    /// Excess over the base per shell, K, and the next step's.
    pub(crate) u: Vec<f64>,
    /// `int_0^r t u(t) dt` at the shell nodes and the outer radius (see
    /// [`RadialGrid::moment`]).
    moments: Vec<f64>,
    next: Vec<f64>,
    /// Heat that went into boiling per shell (whole sphere), J, and the next step's.
    boiled: Vec<f64>,
    boiled_next: Vec<f64>,
    damage: Vec<f64>,
    peak: Vec<f64>,
    scratch: Vec<f64>,
    /// Tissue power queued for the next step, W.
    pub(crate) power: f64,
    /// Whether the last committed step had power.
    pub(crate) powered: bool,
    /// The electrodes whose power is queued ([`electrode_bit`] of each), and those that
    /// powered the last committed step.
    pub(crate) electrodes: u64,
    pub(crate) powered_by: u64,
    /// Heat that crosses the outer radius in the solved step (tissue share), J.
    pub(crate) outflow: f64,
    /// Heat the perfusion carried away in the solved step (tissue share), J.
    pub(crate) perfused: f64,
}

impl Spot {
    /// A spot with no excess; `near`, the coarse nodes around it (node, distance from the
    /// centre and radius of the ball of its lumped volume, m; see [`Spot::coarse_bases`]),
    /// `base` every shell's base until the field sets them ([`Spot::start_bases`]).
    pub(crate) fn new(
        center: Vec3,
        nodes: Vec<(u32, f64)>,
        fraction: f64,
        grid: Arc<RadialGrid>,
        near: &[(u32, f64, f64)],
        base: f64,
    ) -> Self {
        let near = near_nodes(&grid, near);
        Spot {
            center,
            nodes,
            fraction,
            grid,
            near,
            base: vec![base; CELLS],
            next_base: vec![base; CELLS],
            u: vec![0.0; CELLS],
            moments: vec![0.0; CELLS + 1],
            next: vec![0.0; CELLS],
            boiled: vec![0.0; CELLS],
            boiled_next: vec![0.0; CELLS],
            damage: vec![0.0; CELLS],
            peak: vec![base; CELLS],
            scratch: vec![0.0; CELLS],
            power: 0.0,
            powered: false,
            electrodes: 0,
            powered_by: 0,
            outflow: 0.0,
            perfused: 0.0,
        }
    }

    /// Takes other coarse nodes: `nodes` at its centre, `near` around it (as for
    /// [`Spot::new`]); its excess, burns and bases stay (a body's field after a carve: the
    /// same rest shape about it, other nodes).
    pub(crate) fn rebind(&mut self, nodes: Vec<(u32, f64)>, near: &[(u32, f64, f64)]) {
        self.near = near_nodes(&self.grid, near);
        self.nodes = nodes;
    }

    /// Sets the shells' bases, and their peaks to them (a new spot).
    pub(crate) fn start_bases(&mut self, base: Vec<f64>) {
        self.peak.copy_from_slice(&base);
        self.next_base.copy_from_slice(&base);
        self.base = base;
    }

    /// Solves the next step's excess (kept apart until [`Spot::commit`]) over the shells'
    /// bases `next_base`; the heat crossing the outer radius is in `self.outflow`.
    pub(crate) fn solve(&mut self, params: &HeatParams) {
        let g = &*self.grid;
        let source = self.power / self.fraction;
        let perfusion = params.perfusion.coefficient();
        let boil = params.vaporization.boiling_temperature;
        self.next.copy_from_slice(&self.u);
        self.boiled_next.copy_from_slice(&self.boiled);
        let mut outflow = 0.0;
        let mut perfused = 0.0;
        let mut inner = self.first_left(&self.boiled_next);
        for _ in 0..g.substeps {
            // Forward sweep into scratch, back substitution into next. The electrode heats
            // the first shell not vaporized (it has sunk into the crater).
            for i in 0..CELLS {
                let mut d = g.capacity[i] / g.h * self.next[i];
                if i == inner {
                    d += source;
                }
                if i > 0 {
                    d -= g.lower[i] * self.scratch[i - 1];
                }
                self.scratch[i] = d * g.pivot_inv[i];
            }
            self.next[CELLS - 1] = self.scratch[CELLS - 1];
            for i in (0..CELLS - 1).rev() {
                self.next[i] = self.scratch[i] - g.upper[i] * self.next[i + 1];
            }
            outflow += g.conductance[CELLS - 1] * self.next[CELLS - 1] * g.h;
            if perfusion > 0.0 {
                for i in 0..CELLS {
                    perfused += perfusion * g.volume[i] * self.next[i] * g.h;
                }
            }
            // Boiling: heat above the boiling point goes into the water while there is any;
            // in a vaporized shell (the crater) it leaves with the vapour.
            for i in 0..CELLS {
                let over = self.next_base[i] + self.next[i] - boil;
                if over > 0.0 {
                    let room = if i < inner {
                        f64::INFINITY
                    } else {
                        g.latent[i] - self.boiled_next[i]
                    };
                    if room > 0.0 {
                        let take = (g.capacity[i] * over).min(room);
                        self.boiled_next[i] += take;
                        self.next[i] -= take / g.capacity[i];
                    }
                }
            }
            let left = self.first_left(&self.boiled_next);
            // A shell whose water ran out in this pass joins the crater at once.
            for i in inner..left {
                let over = self.next_base[i] + self.next[i] - boil;
                if over > 0.0 {
                    self.boiled_next[i] += g.capacity[i] * over;
                    self.next[i] -= over;
                }
            }
            inner = left;
        }
        self.outflow = self.fraction * outflow;
        self.perfused = self.fraction * perfused;
    }

    /// The first shell whose water is not spent (`CELLS - 1` if all are).
    fn first_left(&self, boiled: &[f64]) -> usize {
        let g = &*self.grid;
        (0..CELLS)
            .find(|&i| !(g.latent[i] > 0.0 && boiled[i] >= g.latent[i] * (1.0 - 1e-12)))
            .unwrap_or(CELLS - 1)
    }

    /// Radius of the crater (the outer face of the last vaporized shell), m; the electrode
    /// radius when nothing vaporized.
    pub(crate) fn crater_radius(&self) -> f64 {
        let g = &*self.grid;
        let i = self.first_left(&self.boiled);
        g.radius * g.ratio.powi(i as i32)
    }

    /// Whether it vaporized beyond the electrode.
    pub(crate) fn has_crater(&self) -> bool {
        self.crater_radius() > self.grid.radius * (1.0 + 1e-9)
    }

    /// Takes the solved step: damage and peaks at each shell's base (`next_base`, the solve's,
    /// kept as `base`) plus its excess, the power spent.
    pub(crate) fn commit(&mut self, params: &HeatParams, dt: f64) {
        std::mem::swap(&mut self.u, &mut self.next);
        std::mem::swap(&mut self.boiled, &mut self.boiled_next);
        std::mem::swap(&mut self.base, &mut self.next_base);
        self.update_moments();
        self.powered = self.power > 0.0;
        self.powered_by = if self.powered { self.electrodes } else { 0 };
        self.power = 0.0;
        self.electrodes = 0;
        for i in 0..CELLS {
            let t = self.base[i] + self.u[i];
            if t > self.peak[i] {
                self.peak[i] = t;
            }
            if params.damage_frequency > 0.0 && t > params.damage_threshold {
                self.damage[i] += dt * arrhenius(params, t);
            }
        }
    }

    /// The excess at `p` (scene units), K.
    pub(crate) fn excess_at(&self, p: &Vec3, meters_per_unit: f64) -> f64 {
        let d = (p - self.center).norm() * meters_per_unit;
        self.grid.excess(&self.u, d)
    }

    /// Largest excess, K.
    pub(crate) fn max_excess(&self) -> f64 {
        self.u.iter().copied().fold(0.0, crate::state::nan_max)
    }

    /// Largest temperature of a shell (its base and excess), C.
    pub(crate) fn max_temperature(&self) -> f64 {
        self.base
            .iter()
            .zip(&self.u)
            .map(|(b, u)| b + u)
            .fold(f64::NEG_INFINITY, crate::state::nan_max)
    }

    /// Recomputes [`Spot::moments`] from the excess.
    fn update_moments(&mut self) {
        let g = &*self.grid;
        self.moments[0] = 0.5 * self.u[0] * g.r[0] * g.r[0];
        for i in 0..CELLS {
            let (r1, u1) = if i + 1 < CELLS {
                (g.r[i + 1], self.u[i + 1])
            } else {
                (g.outer, 0.0)
            };
            self.moments[i + 1] = self.moments[i] + piece_moment(g.r[i], self.u[i], r1, u1, r1);
        }
    }

    /// Adds to each `out[i]` the mean of its excess over the sphere of radius `r[i]` (m)
    /// about `centre` (scene units), K: for a sphere whose centre is `d` from its own, the
    /// mean of a radial `u` is `int_{|r-d|}^{r+d} t u(t) dt / (2 r d)`.
    pub(crate) fn add_sphere_means(
        &self,
        centre: &Vec3,
        meters_per_unit: f64,
        r: &[f64],
        out: &mut [f64],
    ) {
        let g = &*self.grid;
        let d = (centre - self.center).norm() * meters_per_unit;
        for (o, &ri) in out.iter_mut().zip(r) {
            if d >= g.outer + ri {
                continue;
            }
            *o += if d <= 1e-6 * ri {
                g.excess(&self.u, ri)
            } else {
                let m = |x: f64| g.moment(&self.u, &self.moments, x);
                (m(ri + d) - m((ri - d).abs())) / (2.0 * ri * d)
            };
        }
    }

    /// The coarse field around it per shell into `out`, C: the mean temperature of the ball
    /// out to the shell, where each node nearby counts with its lumped volume's share in the
    /// ball (taken as a ball of that volume about the node, its share rising linearly across
    /// it) and tissue no node reaches is at the temperature of its surroundings (the nodes
    /// within its outer radius); `centre`, the field at its centre, where no node is near.
    /// So a crater's small nodes, heated by the spot carved out, warm its first shells by
    /// what they hold, not the whole 20 mm.
    pub(crate) fn coarse_bases(
        &self,
        temperature: &[f64],
        capacity: &[f64],
        rho_c: f64,
        centre: f64,
        out: &mut [f64],
    ) {
        let g = &*self.grid;
        let (mut held, mut cap) = (0.0, 0.0);
        for p in &self.near {
            let c = p.far * capacity[p.node as usize];
            held += c * temperature[p.node as usize];
            cap += c;
        }
        let around = if cap > 0.0 { held / cap } else { centre };
        // Per shell: the capacity and the heat above `around` of the nodes inside, those
        // partly inside shell by shell, those wholly inside from their first such shell on.
        let mut partial = [(0.0, 0.0); CELLS];
        let mut whole = [(0.0, 0.0); CELLS + 1];
        for p in &self.near {
            let c = capacity[p.node as usize];
            let h = c * (temperature[p.node as usize] - around);
            let shells = p.first..p.last;
            for (sum, r) in partial[shells.clone()].iter_mut().zip(&g.r[shells]) {
                let f = (r - p.inside) * p.per_metre;
                sum.0 += f * c;
                sum.1 += f * h;
            }
            whole[p.last].0 += c;
            whole[p.last].1 += h;
        }
        let (mut wc, mut wh) = (0.0, 0.0);
        let sphere = self.fraction * rho_c * 4.0 / 3.0 * std::f64::consts::PI;
        for i in 0..CELLS {
            wc += whole[i].0;
            wh += whole[i].1;
            let (c, h) = (wc + partial[i].0, wh + partial[i].1);
            let ball = sphere * g.r[i].powi(3);
            out[i] = around + if c > 0.0 { h / c.max(ball) } else { 0.0 };
        }
    }

    /// Heat it holds (tissue share): its excess and the heat its water took, J.
    pub(crate) fn energy(&self) -> f64 {
        let g = &*self.grid;
        let sensible: f64 = g.capacity.iter().zip(&self.u).map(|(c, u)| c * u).sum();
        let boiled: f64 = self.boiled.iter().sum();
        self.fraction * (sensible + boiled)
    }

    /// Whether cell `i`'s tissue has vaporized (its water all boiled).
    fn cell_vaporized(&self, i: usize) -> bool {
        let latent = self.grid.latent[i];
        latent > 0.0 && self.boiled[i] >= latent * (1.0 - 1e-12)
    }

    /// Heat in the excess of its tissue that is still there (tissue share), J: what the
    /// coarse field takes when it ends. The cells that vaporized hold none of it: their
    /// tissue left as steam (see [`Spot::vaporized_sensible_energy`]).
    pub(crate) fn sensible_energy(&self) -> f64 {
        let g = &*self.grid;
        self.fraction
            * (0..CELLS)
                .filter(|&i| !self.cell_vaporized(i))
                .map(|i| g.capacity[i] * self.u[i])
                .sum::<f64>()
    }

    /// Heat in the excess of its vaporized cells (tissue share), J: the sensible heat of
    /// tissue that left as steam. Given to no node when the spot ends (pressed into the
    /// few nodes at a crater's wall it heated them hundreds of kelvin above boiling).
    pub(crate) fn vaporized_sensible_energy(&self) -> f64 {
        let g = &*self.grid;
        self.fraction
            * (0..CELLS)
                .filter(|&i| self.cell_vaporized(i))
                .map(|i| g.capacity[i] * self.u[i])
                .sum::<f64>()
    }

    /// Heat its water took (tissue share), J.
    pub(crate) fn boiled_energy(&self) -> f64 {
        self.fraction * self.boiled.iter().sum::<f64>()
    }

    /// Its burnt volumes (tissue share), m^3.
    pub(crate) fn volumes(&self, params: &HeatParams) -> BurnVolumes {
        let g = &*self.grid;
        let mut v = BurnVolumes::default();
        let boil = params.vaporization.boiling_temperature;
        for i in 0..CELLS {
            let share = self.fraction * g.volume[i];
            if self.damage[i] >= 1.0 {
                v.coagulated += share;
            }
            if self.boiled[i] > 0.0 || self.peak[i] >= boil {
                v.charred += share;
            }
            if self.cell_vaporized(i) {
                v.vaporized += share;
            }
        }
        v
    }

    /// Radius of the coagulated zone (damage at least 1), m (0 when none).
    pub(crate) fn coagulated_radius(&self) -> f64 {
        let g = &*self.grid;
        (0..CELLS)
            .filter(|&i| self.damage[i] >= 1.0)
            .map(|i| g.r[i])
            .fold(0.0, f64::max)
    }
}

/// A coarse node around a spot, whose lumped volume (taken as a ball about the node) reaches
/// within the spot's outer radius: its share of that ball inside the spot's sphere (its outer
/// radius), the shells the ball's surface crosses (`first..last`; from `last` on it is all
/// inside), and its share in the ball out to radius `r` there, `(r - inside) * per_metre`.
/// The coarse nodes around a spot (node, distance from its centre and radius of the ball
/// of its lumped volume, m) as its shells see them.
fn near_nodes(grid: &RadialGrid, near: &[(u32, f64, f64)]) -> Vec<NearNode> {
    near.iter()
        .map(|&(node, d, a)| NearNode {
            node,
            far: ((grid.outer - d + a) / (2.0 * a)).clamp(0.0, 1.0),
            first: grid.r.partition_point(|&r| r <= d - a),
            last: grid.r.partition_point(|&r| r < d + a),
            inside: d - a,
            per_metre: 0.5 / a,
        })
        .collect()
}

#[derive(Debug, Clone)]
struct NearNode {
    node: u32,
    far: f64,
    first: usize,
    last: usize,
    inside: f64,
    per_metre: f64,
}

/// What a spot burnt, by distance from its centre: kept when it ends or when the body's mesh
/// changes (a cut, a carve), so the points a burn is drawn at start from it.
#[derive(Debug, Clone)]
pub(crate) struct BurnMark {
    pub(crate) center: Vec3,
    /// Node radius of each shell, m, and its damage and peak temperature.
    r: Vec<f64>,
    damage: Vec<f64>,
    peak: Vec<f64>,
}

impl Spot {
    /// Its burn (see [`BurnMark`]).
    pub(crate) fn mark(&self) -> BurnMark {
        BurnMark {
            center: self.center,
            r: self.grid.r.clone(),
            damage: self.damage.clone(),
            peak: self.peak.clone(),
        }
    }
}

impl BurnMark {
    /// Damage and peak temperature at `d` m from the centre: those of the shell there (the
    /// first within the electrode's radius); `None` beyond the last shell.
    pub(crate) fn at(&self, d: f64) -> Option<(f64, f64)> {
        if d > *self.r.last()? {
            return None;
        }
        let i = self.r.partition_point(|&r| r < d).min(self.r.len() - 1);
        Some((self.damage[i], self.peak[i]))
    }
}

/// Arrhenius damage rate at `t` C, 1/s.
pub(crate) fn arrhenius(params: &HeatParams, t: f64) -> f64 {
    params.damage_frequency
        * (-params.damage_activation_energy / (GAS_CONSTANT * (t + KELVIN_OFFSET))).exp()
}
