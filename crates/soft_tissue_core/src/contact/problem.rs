//! The contact problem of one step: Signorini and Coulomb conditions on contact rows, coupled
//! through the bodies' compliances (the Delassus operator), solved by projected Gauss-Seidel.
//!
//! A row joins a point of a body (side `a`, a vertex or a point of a triangle) to a point of
//! another body, a tool or an obstacle. Its frame holds the contact normal (the way side `a`
//! is pushed) and two tangents; its unknown is the force on side `a` in that frame (the other
//! side takes the opposite), held over the step. A body answers a force `f` on its surface
//! vertices with a displacement `C f` at the end of the step, `C` its compliance (for an
//! implicit integrator `h^2 A^-1`, `A` the step's system matrix; see
//! [`crate::precision::LeveledModel::contact_compliance`]). With `W = J C J^T` (the Delassus
//! operator, `J` the rows' frames and weights), the relative displacement of a row after the
//! correction is `r = b + W lambda`, `b` its gap and slip before it, and each row meets
//!
//! ```text
//! Signorini:  r_n >= 0,  lambda_n >= 0,  r_n lambda_n = 0          (no penetration, no pull)
//! Coulomb:    |lambda_t| <= mu lambda_n; r_t = 0 while |lambda_t| < mu lambda_n (stick),
//!             otherwise lambda_t = -mu lambda_n r_t / |r_t|                      (slide)
//! ```
//!
//! with the static coefficient first (a contact sticks whenever static friction can stop its
//! slip within the step, as velocity-level Coulomb friction does), and the kinetic one for a
//! row that slides even so (the solve is run once more with it). Attachments (a grab) are bilateral: `r = 0`, any force.
//! Projected Gauss-Seidel (Duriez, Dubois, Kheddar and Andriot, IEEE TVCG 12(1), 2006, as in
//! SOFA's constraint solver) sweeps the rows in order, one 3x3 block at a time: deterministic,
//! and warm-started from the last step's forces it converges in a few sweeps at rest.
//!
//! `W` is block-sparse: two rows are coupled when they share a body. Each body's compliance
//! is gathered once per assembly on the distinct vertices its rows touch.

use nalgebra::{Matrix2, Matrix3, Vector2};

use crate::Vec3;

/// A point of a body's surface: up to three of its surface vertices (collider indices) with
/// weights summing to one (a vertex has one).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyPoint {
    /// Body index.
    pub body: u32,
    /// Surface vertices (collider indices); unused entries repeat the first with weight 0.
    pub vertices: [u32; 3],
    /// Weights.
    pub weights: [f64; 3],
}

impl BodyPoint {
    /// A surface vertex.
    pub fn vertex(body: u32, vertex: u32) -> Self {
        BodyPoint {
            body,
            vertices: [vertex; 3],
            weights: [1.0, 0.0, 0.0],
        }
    }

    /// A point of a triangle with barycentric `weights`.
    pub fn triangle(body: u32, vertices: [u32; 3], weights: [f64; 3]) -> Self {
        BodyPoint {
            body,
            vertices,
            weights,
        }
    }

    /// The vertices with a weight, and their weights.
    pub fn terms(&self) -> impl Iterator<Item = (u32, f64)> + '_ {
        (0..3)
            .filter(|&k| self.weights[k] != 0.0)
            .map(|k| (self.vertices[k], self.weights[k]))
    }

    /// The point's position from the surface vertex positions `x`.
    pub fn position(&self, x: &[Vec3]) -> Vec3 {
        self.terms().map(|(v, w)| x[v as usize] * w).sum()
    }
}

/// What the other side of a row is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Counterpart {
    /// A point of another body (pushed along minus the normal).
    Body(BodyPoint),
    /// A part of a tool (its tip, or one jaw of a grasper); kinematic.
    Tool {
        /// Tool index.
        tool: u32,
        /// Part of the tool (0: the tip or the first jaw, 1: the second jaw).
        part: u8,
    },
    /// A static obstacle.
    Obstacle(u32),
}

/// The condition a row imposes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RowKind {
    /// Unilateral contact with Coulomb friction.
    Contact {
        /// Static friction coefficient (holds a contact that it can stop within the step).
        static_friction: f64,
        /// Kinetic friction coefficient (a contact that slides even so).
        kinetic_friction: f64,
    },
    /// Bilateral attachment: the relative displacement is held at zero in every direction.
    Attachment,
}

/// A key that follows a row from step to step (warm start, stick or slide): side `a`'s body,
/// its feature (the vertices of the point with a weight, sorted, `u32::MAX` after them), the
/// counterpart's kind and index, and for another body the triangle's vertices (sorted).
pub type RowKey = [u32; 9];

/// Counterpart kinds in a [`RowKey`].
pub(crate) const KEY_BODY: u32 = 0;
pub(crate) const KEY_TOOL: u32 = 1;
pub(crate) const KEY_OBSTACLE: u32 = 2;
pub(crate) const KEY_GRIP: u32 = 3;

/// One row of the contact problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactRow {
    /// Identity across steps.
    pub key: RowKey,
    /// The body point pushed along the normal.
    pub a: BodyPoint,
    /// The other side.
    pub other: Counterpart,
    /// Columns: the unit normal (the way `a` is pushed), then two unit tangents.
    pub frame: Matrix3<f64>,
    /// Normal gap at the current positions (negative: penetration beyond the contact
    /// distance).
    pub gap: f64,
    /// Tangential displacement of `a` relative to the other side since the start of the step.
    pub slip: [f64; 2],
    /// Contact or attachment.
    pub kind: RowKind,
    /// The force on `a`, in the frame (normal, tangents): the solution.
    pub force: Vec3,
    /// The part of `force` already applied to the bodies in this step (earlier rounds).
    pub applied: Vec3,
    /// Whether the row slides (uses its kinetic coefficient).
    pub sliding: bool,
}

impl ContactRow {
    /// A contact row with no force yet.
    #[allow(clippy::too_many_arguments)]
    pub fn contact(
        key: RowKey,
        a: BodyPoint,
        other: Counterpart,
        normal: Vec3,
        gap: f64,
        relative_motion: Vec3,
        static_friction: f64,
        kinetic_friction: f64,
    ) -> Self {
        let frame = frame_of(&normal);
        let slip = [
            frame.column(1).dot(&relative_motion),
            frame.column(2).dot(&relative_motion),
        ];
        ContactRow {
            key,
            a,
            other,
            frame,
            gap,
            slip,
            kind: RowKind::Contact {
                static_friction,
                kinetic_friction,
            },
            force: Vec3::zeros(),
            applied: Vec3::zeros(),
            sliding: false,
        }
    }

    /// An attachment holding the relative displacement `offset` (current minus wanted) at
    /// zero.
    pub fn attachment(key: RowKey, a: BodyPoint, other: Counterpart, offset: Vec3) -> Self {
        // The world axes as the frame: gap and slips are the offset's components.
        ContactRow {
            key,
            a,
            other,
            frame: Matrix3::identity(),
            gap: offset.x,
            slip: [offset.y, offset.z],
            kind: RowKind::Attachment,
            force: Vec3::zeros(),
            applied: Vec3::zeros(),
            sliding: false,
        }
    }

    /// The force on side `a` in world coordinates.
    pub fn world_force(&self) -> Vec3 {
        self.frame * self.force
    }

    /// The unit normal.
    pub fn normal(&self) -> Vec3 {
        self.frame.column(0).into_owned()
    }

    /// Whether the row is a unilateral contact.
    pub fn is_contact(&self) -> bool {
        matches!(self.kind, RowKind::Contact { .. })
    }
}

/// An orthonormal frame whose first column is `n` (unit), the tangents chosen by a fixed
/// rule so that equal normals give equal frames.
pub fn frame_of(n: &Vec3) -> Matrix3<f64> {
    let helper = if n.x.abs() < 0.57 {
        Vec3::x()
    } else if n.y.abs() < 0.57 {
        Vec3::y()
    } else {
        Vec3::z()
    };
    let t1 = (helper - n * n.dot(&helper)).normalize();
    let t2 = n.cross(&t1);
    Matrix3::from_columns(&[*n, t1, t2])
}

/// Settings of the projected Gauss-Seidel solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverSettings {
    /// Most sweeps over the rows.
    pub max_sweeps: u32,
    /// Stops when no force changed by more than this fraction of the largest force in a sweep.
    pub tolerance: f64,
    /// Stops too when every row that can move meets its conditions to this distance (scene
    /// units; 0: never): a pressed row's gap closed, a free row not penetrating, a sticking
    /// row not slipping, an attachment held. Rows that say the same thing (the two sides of
    /// a cut pressed together, each side's vertices against the other's triangles) leave
    /// the forces free to shift between them without end while the motion is already
    /// found: this ends the solve there.
    pub gap_tolerance: f64,
}

impl Default for SolverSettings {
    fn default() -> Self {
        SolverSettings {
            max_sweeps: 200,
            tolerance: 1e-7,
            gap_tolerance: 0.0,
        }
    }
}

/// What a solve did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SolveStats {
    /// Rows.
    pub rows: u32,
    /// Sweeps taken (both phases).
    pub sweeps: u32,
    /// Largest change of a force in the last sweep, relative to the largest force.
    pub change: f64,
    /// Rows that slide at the end.
    pub sliding: u32,
}

/// One vertex term of a row on a body.
#[derive(Debug, Clone, Copy)]
struct Incidence {
    body: u32,
    row: u32,
    /// Index of the vertex among the body's distinct contact vertices.
    local: u32,
    vertex: u32,
    /// Weight, with the side's sign (+ for side `a`).
    coef: f64,
}

/// `compliance(body, vertices, out)`: the body's compliance blocks between the given surface
/// vertices (see [`ContactSolver::assemble`]); it writes every block of `out`.
pub type Compliance<'a> = dyn FnMut(u32, &[u32], &mut [Matrix3<f64>]) + 'a;

/// `each(body, forces)`: forces on a body's surface vertices (see [`ContactSolver::apply`]).
pub type ForcesOn<'a> = dyn FnMut(u32, &[(u32, Vec3)]) + 'a;

/// Assembly and solve workspaces (reused from step to step: no allocation once grown).
#[derive(Debug, Default, Clone)]
pub struct ContactSolver {
    incidences: Vec<Incidence>,
    /// Per body with rows: (body, range in `incidences`, range in `vertices`, offset in
    /// `gathered`).
    bodies: Vec<(u32, std::ops::Range<usize>, std::ops::Range<usize>, usize)>,
    vertices: Vec<u32>,
    gathered: Vec<Matrix3<f64>>,
    /// Rows of each body, in `bodies` order (ranges in `body_rows`).
    body_rows: Vec<u32>,
    body_row_ranges: Vec<std::ops::Range<usize>>,
    // The Delassus operator, block CSR over rows.
    start: Vec<u32>,
    cols: Vec<u32>,
    blocks: Vec<Matrix3<f64>>,
    diag: Vec<u32>,
    /// Per row: inverse of the tangential 2x2 block and of the whole block.
    tangent_inv: Vec<Matrix2<f64>>,
    block_inv: Vec<Matrix3<f64>>,
    b: Vec<Vec3>,
    scratch: Vec<u32>,
    forces: Vec<(u32, Vec3)>,
    summed: Vec<Vec3>,
}

/// Finds the local index of `vertex` in a sorted list.
fn local_of(list: &[u32], vertex: u32) -> u32 {
    list.binary_search(&vertex).expect("gathered above") as u32
}

impl ContactSolver {
    /// Builds the Delassus operator of `rows`. `compliance(body, vertices, out)` writes all
    /// the body's compliance blocks between the given surface vertices into `out` (row-major,
    /// `vertices.len()^2` blocks, world frame: block `(i, j)` is the displacement of vertex
    /// `i` per unit force on vertex `j` over the step).
    pub fn assemble(&mut self, rows: &[ContactRow], compliance: &mut Compliance<'_>) {
        self.incidences.clear();
        for (r, row) in rows.iter().enumerate() {
            let mut push = |p: &BodyPoint, sign: f64| {
                for (v, w) in p.terms() {
                    self.incidences.push(Incidence {
                        body: p.body,
                        row: r as u32,
                        local: 0,
                        vertex: v,
                        coef: sign * w,
                    });
                }
            };
            push(&row.a, 1.0);
            if let Counterpart::Body(p) = &row.other {
                push(p, -1.0);
            }
        }
        self.incidences
            .sort_unstable_by_key(|i| (i.body, i.row, i.vertex));
        // Bodies, their distinct vertices and gathered compliances.
        self.bodies.clear();
        self.vertices.clear();
        self.body_rows.clear();
        self.body_row_ranges.clear();
        let mut gathered_len = 0;
        let mut k = 0;
        while k < self.incidences.len() {
            let body = self.incidences[k].body;
            let end = k + self.incidences[k..]
                .iter()
                .position(|i| i.body != body)
                .unwrap_or(self.incidences.len() - k);
            let vstart = self.vertices.len();
            self.vertices
                .extend(self.incidences[k..end].iter().map(|i| i.vertex));
            self.vertices[vstart..].sort_unstable();
            let distinct = {
                let list = &mut self.vertices[vstart..];
                let mut n = 0;
                for j in 0..list.len() {
                    if n == 0 || list[j] != list[n - 1] {
                        list[n] = list[j];
                        n += 1;
                    }
                }
                n
            };
            self.vertices.truncate(vstart + distinct);
            for i in &mut self.incidences[k..end] {
                i.local = local_of(&self.vertices[vstart..], i.vertex);
            }
            let rstart = self.body_rows.len();
            for i in &self.incidences[k..end] {
                if self.body_rows.len() == rstart || *self.body_rows.last().unwrap() != i.row {
                    self.body_rows.push(i.row);
                }
            }
            self.body_row_ranges.push(rstart..self.body_rows.len());
            self.bodies
                .push((body, k..end, vstart..vstart + distinct, gathered_len));
            gathered_len += distinct * distinct;
            k = end;
        }
        // Every block is written by `compliance` (no zeroing first: at a crater's 124 rows
        // these are a megabyte a step).
        self.gathered.resize(gathered_len, Matrix3::zeros());
        for (body, _, vr, off) in &self.bodies {
            let n = vr.len();
            compliance(
                *body,
                &self.vertices[vr.clone()],
                &mut self.gathered[*off..*off + n * n],
            );
        }
        // Pattern: row c couples with every row sharing a body.
        let n = rows.len();
        self.start.clear();
        self.cols.clear();
        for row in rows {
            self.start.push(self.cols.len() as u32);
            self.scratch.clear();
            let mut touched = 0;
            for (bi, (body, ..)) in self.bodies.iter().enumerate() {
                let on = |p: &BodyPoint| p.body == *body;
                let touches = on(&row.a) || matches!(&row.other, Counterpart::Body(p) if on(p));
                if touches {
                    touched += 1;
                    self.scratch
                        .extend_from_slice(&self.body_rows[self.body_row_ranges[bi].clone()]);
                }
            }
            // One body's rows are sorted and distinct already (gathered in row order).
            if touched > 1 {
                self.scratch.sort_unstable();
                self.scratch.dedup();
            }
            self.cols.extend_from_slice(&self.scratch);
        }
        self.start.push(self.cols.len() as u32);
        // The blocks on and above the diagonal are summed into, so they start at zero; those
        // below are written whole by the frames' pass.
        self.blocks.resize(self.cols.len(), Matrix3::zeros());
        for c in 0..n {
            for j in self.start[c] as usize..self.start[c + 1] as usize {
                if self.cols[j] as usize >= c {
                    self.blocks[j] = Matrix3::zeros();
                }
            }
        }
        // G blocks (world frame), body by body, on and above the diagonal only (the frames
        // below mirror them). A row's couplings on one body come in column order, so the
        // place of each is found by walking the row's pattern, not by searching it.
        for (bi, (_, ir, vr, off)) in self.bodies.iter().enumerate() {
            let nv = vr.len();
            let inc = &self.incidences[ir.clone()];
            let rows_of = &self.body_rows[self.body_row_ranges[bi].clone()];
            // Incidences of each row of this body are contiguous (sorted by row).
            let mut pos = 0;
            for &row in rows_of {
                let s = pos;
                while pos < inc.len() && inc[pos].row == row {
                    pos += 1;
                }
                let rc = row as usize;
                let mut at = self.start[rc] as usize;
                // Pair (row, d) for every row d of this body from `row` on (the gathered
                // compliance is symmetric: (d, row) is the transpose): walk d's incidences.
                let mut q = 0;
                for &d in rows_of {
                    let t = q;
                    while q < inc.len() && inc[q].row == d {
                        q += 1;
                    }
                    if d < row {
                        continue;
                    }
                    let mut g = Matrix3::zeros();
                    for ia in &inc[s..pos] {
                        for ib in &inc[t..q] {
                            g += self.gathered[off + ia.local as usize * nv + ib.local as usize]
                                * (ia.coef * ib.coef);
                        }
                    }
                    while self.cols[at] < d {
                        at += 1;
                    }
                    debug_assert_eq!(self.cols[at], d, "pattern");
                    self.blocks[at] += g;
                }
            }
        }
        // Into the rows' frames; inverses of the diagonal blocks. Rows are taken in order, so
        // the blocks below the diagonal of each row d are reached in column order too: a
        // cursor per row (`scratch`) finds their places.
        self.diag.clear();
        self.tangent_inv.clear();
        self.block_inv.clear();
        self.scratch.clear();
        self.scratch.extend_from_slice(&self.start[..n]);
        for c in 0..n {
            let (lo, hi) = (self.start[c] as usize, self.start[c + 1] as usize);
            let fc = rows[c].frame.transpose();
            // From the diagonal on; the block below it is the transpose (W is symmetric).
            for j in lo..hi {
                let d = self.cols[j] as usize;
                if d < c {
                    continue;
                }
                let mut b = fc * self.blocks[j] * rows[d].frame;
                if d == c {
                    b = (b + b.transpose()) * 0.5;
                }
                self.blocks[j] = b;
                if d != c {
                    let mut k = self.scratch[d] as usize;
                    while self.cols[k] < c as u32 {
                        k += 1;
                    }
                    debug_assert_eq!(self.cols[k], c as u32, "pattern");
                    self.blocks[k] = b.transpose();
                    self.scratch[d] = k as u32 + 1;
                }
            }
            let dj = lo
                + self.cols[lo..hi]
                    .binary_search(&(c as u32))
                    .expect("a row couples with itself");
            self.diag.push(dj as u32);
            let w = self.blocks[dj];
            let wt = Matrix2::new(w[(1, 1)], w[(1, 2)], w[(2, 1)], w[(2, 2)]);
            self.tangent_inv
                .push(wt.try_inverse().unwrap_or_else(Matrix2::zeros));
            self.block_inv
                .push(w.try_inverse().unwrap_or_else(Matrix3::zeros));
        }
    }

    /// Whether anything can move row `c` of the last assembly along its normal (its
    /// diagonal compliance is positive; not so for fixed nodes against a tool or each
    /// other).
    pub fn movable(&self, c: usize) -> bool {
        self.blocks[self.diag[c] as usize][(0, 0)] > 0.0
    }

    /// The assembled Delassus block between rows `c` and `d` (row frames), if they couple.
    pub fn block(&self, c: usize, d: usize) -> Option<Matrix3<f64>> {
        let (lo, hi) = (self.start[c] as usize, self.start[c + 1] as usize);
        self.cols[lo..hi]
            .binary_search(&(d as u32))
            .ok()
            .map(|j| self.blocks[lo + j])
    }

    /// Solves the rows' forces (in place, warm-started from their `force`), for the
    /// relative displacements `b + W (lambda - applied)` with `b = (gap, slip)`.
    pub fn solve(&mut self, rows: &mut [ContactRow], settings: &SolverSettings) -> SolveStats {
        let n = rows.len();
        self.b.clear();
        for c in 0..n {
            let mut b = Vec3::new(rows[c].gap, rows[c].slip[0], rows[c].slip[1]);
            let (lo, hi) = (self.start[c] as usize, self.start[c + 1] as usize);
            for j in lo..hi {
                b -= self.blocks[j] * rows[self.cols[j] as usize].applied;
            }
            self.b.push(b);
        }
        let mut stats = SolveStats {
            rows: n as u32,
            ..SolveStats::default()
        };
        // Phase one with the static coefficients (a row sticks whenever static friction can
        // stop its slip within the step); phase two once more with the kinetic coefficient
        // for the rows that slide even so.
        for r in rows.iter_mut() {
            r.sliding = false;
        }
        for _phase in 0..2 {
            let (sweeps, change) = self.sweeps(rows, settings);
            stats.sweeps += sweeps;
            stats.change = change;
            let mut switched = false;
            for c in 0..n {
                if let RowKind::Contact {
                    static_friction,
                    kinetic_friction,
                } = rows[c].kind
                {
                    let f = rows[c].force;
                    let tangential = Vector2::new(f.y, f.z).norm();
                    let mu = if rows[c].sliding {
                        kinetic_friction
                    } else {
                        static_friction
                    };
                    let saturated = f.x > 0.0 && tangential >= mu * f.x * (1.0 - 1e-9);
                    let slip = self.residual(rows, c);
                    let moving = Vector2::new(slip.y, slip.z).norm()
                        > 1e-9 * (1e-300 + slip.x.abs().max(rows[c].gap.abs()));
                    if saturated && moving && !rows[c].sliding {
                        rows[c].sliding = true;
                        switched |= static_friction != kinetic_friction;
                    } else if !saturated && rows[c].sliding {
                        // Held within the cone: it sticks.
                        rows[c].sliding = false;
                    }
                }
            }
            if !switched {
                break;
            }
        }
        stats.sliding = rows.iter().filter(|r| r.sliding).count() as u32;
        stats
    }

    /// `b + W lambda` of row `c`.
    fn residual(&self, rows: &[ContactRow], c: usize) -> Vec3 {
        let (lo, hi) = (self.start[c] as usize, self.start[c + 1] as usize);
        let mut r = self.b[c];
        for j in lo..hi {
            // Rows without force add nothing (at a crater about half the rows are candidates
            // that never touch).
            let f = rows[self.cols[j] as usize].force;
            if f != Vec3::zeros() {
                r += self.blocks[j] * f;
            }
        }
        r
    }

    /// Sweeps until converged; returns the sweeps and the last relative change.
    fn sweeps(&self, rows: &mut [ContactRow], settings: &SolverSettings) -> (u32, f64) {
        let n = rows.len();
        let mut last = 0.0;
        for sweep in 1..=settings.max_sweeps.max(1) {
            let mut change: f64 = 0.0;
            let mut largest: f64 = 0.0;
            // How far the rows were from their conditions as the sweep reached them.
            let mut unmet: f64 = 0.0;
            for c in 0..n {
                let r = self.residual(rows, c);
                let w = self.blocks[self.diag[c] as usize];
                let old = rows[c].force;
                let new = match rows[c].kind {
                    RowKind::Attachment => {
                        unmet = unmet.max(r.norm());
                        old - self.block_inv[c] * r
                    }
                    RowKind::Contact {
                        static_friction,
                        kinetic_friction,
                    } => {
                        let wnn = w[(0, 0)];
                        if wnn <= 0.0 {
                            // Nothing on either side can move along this normal.
                            Vec3::zeros()
                        } else {
                            unmet = unmet.max(if old.x > 0.0 { r.x.abs() } else { -r.x });
                            let mu = if rows[c].sliding {
                                kinetic_friction
                            } else {
                                static_friction
                            };
                            let held = Vector2::new(old.y, old.z).norm();
                            if old.x > 0.0 && held < mu * old.x * (1.0 - 1e-6) {
                                unmet = unmet.max(Vector2::new(r.y, r.z).norm());
                            }
                            let ln = (old.x - r.x / wnn).max(0.0);
                            let dn = ln - old.x;
                            let rt = Vector2::new(r.y + w[(1, 0)] * dn, r.z + w[(2, 0)] * dn);
                            let mut lt = Vector2::new(old.y, old.z) - self.tangent_inv[c] * rt;
                            let mu = if rows[c].sliding {
                                kinetic_friction
                            } else {
                                static_friction
                            };
                            let cap = mu * ln;
                            let norm = lt.norm();
                            if norm > cap {
                                lt *= if norm > 0.0 { cap / norm } else { 0.0 };
                            }
                            Vec3::new(ln, lt.x, lt.y)
                        }
                    }
                };
                rows[c].force = new;
                change = change.max((new - old).amax());
                largest = largest.max(new.amax());
            }
            last = if largest > 0.0 { change / largest } else { 0.0 };
            let met = settings.gap_tolerance > 0.0 && unmet <= settings.gap_tolerance;
            if last <= settings.tolerance || met || !last.is_finite() {
                return (sweep, last);
            }
        }
        (settings.max_sweeps.max(1), last)
    }

    /// The forces still to apply (`force - applied` of every row, world frame) on each body's
    /// surface vertices: `each(body, forces)` with `(vertex, force)` pairs (each vertex once,
    /// in increasing order; none with a zero force). Marks the forces applied.
    pub fn apply(&mut self, rows: &mut [ContactRow], each: &mut ForcesOn<'_>) {
        for (_, ir, vr, _) in &self.bodies {
            let body = self.incidences[ir.start].body;
            // Summed per vertex (rows on triangles share them), in vertex order.
            self.summed.clear();
            self.summed.resize(vr.len(), Vec3::zeros());
            for i in &self.incidences[ir.clone()] {
                let row = &rows[i.row as usize];
                self.summed[i.local as usize] += row.frame * (row.force - row.applied) * i.coef;
            }
            self.forces.clear();
            self.forces.extend(
                self.vertices[vr.clone()]
                    .iter()
                    .zip(&self.summed)
                    .filter(|(_, f)| **f != Vec3::zeros())
                    .map(|(&v, &f)| (v, f)),
            );
            if !self.forces.is_empty() {
                each(body, &self.forces);
            }
        }
        for r in rows.iter_mut() {
            r.applied = r.force;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A compliance that is `c` times the identity on each vertex (no coupling between
    /// vertices): body `b`'s vertex `v` moves by `c_b f`.
    fn diagonal(cs: &'static [f64]) -> impl FnMut(u32, &[u32], &mut [Matrix3<f64>]) {
        move |b, v, out| {
            let n = v.len();
            for i in 0..n {
                for j in 0..n {
                    out[i * n + j] = if i == j {
                        Matrix3::identity() * cs[b as usize]
                    } else {
                        Matrix3::zeros()
                    };
                }
            }
        }
    }

    fn row(a: BodyPoint, other: Counterpart, n: Vec3, gap: f64, slip: Vec3, mu: f64) -> ContactRow {
        ContactRow::contact([0; 9], a, other, n, gap, slip, mu, mu)
    }

    /// One vertex 0.1 inside a rigid plane with compliance 0.01: the force that closes the
    /// gap is 10, and the corrected gap is zero; a vertex outside gets no force.
    #[test]
    fn a_single_contact_closes_its_gap_and_never_pulls() {
        let mut s = ContactSolver::default();
        let mut rows = vec![
            row(
                BodyPoint::vertex(0, 0),
                Counterpart::Obstacle(0),
                Vec3::y(),
                -0.1,
                Vec3::zeros(),
                0.0,
            ),
            row(
                BodyPoint::vertex(0, 1),
                Counterpart::Obstacle(0),
                Vec3::y(),
                0.05,
                Vec3::zeros(),
                0.0,
            ),
        ];
        s.assemble(&rows, &mut diagonal(&[0.01]));
        s.solve(&mut rows, &SolverSettings::default());
        assert!((rows[0].force.x - 10.0).abs() < 1e-9, "{:?}", rows[0].force);
        assert_eq!(rows[1].force, Vec3::zeros());
        let mut moved = [Vec3::zeros(); 2];
        s.apply(&mut rows, &mut |_, f| {
            for (v, f) in f {
                moved[*v as usize] += f * 0.01;
            }
        });
        assert!((moved[0].y - 0.1).abs() < 1e-12);
    }

    /// Two bodies pressed together: the correction is split by their compliances (the
    /// softer moves more) and the forces are equal and opposite.
    #[test]
    fn two_bodies_share_a_correction_by_compliance() {
        let mut s = ContactSolver::default();
        let mut rows = vec![row(
            BodyPoint::vertex(0, 0),
            Counterpart::Body(BodyPoint::vertex(1, 0)),
            Vec3::x(),
            -0.3,
            Vec3::zeros(),
            0.0,
        )];
        s.assemble(&rows, &mut diagonal(&[0.01, 0.02]));
        s.solve(&mut rows, &SolverSettings::default());
        // 0.3 = (0.01 + 0.02) f.
        assert!((rows[0].force.x - 10.0).abs() < 1e-9);
        let mut moved = [Vec3::zeros(); 2];
        s.apply(&mut rows, &mut |b, f| {
            for (_, f) in f {
                moved[b as usize] += f * [0.01, 0.02][b as usize];
            }
        });
        assert!((moved[0].x - 0.1).abs() < 1e-12 && (moved[1].x + 0.2).abs() < 1e-12);
    }

    /// Coulomb: holding a tangential slip of 0.2 at compliance 0.01 takes a friction force of
    /// 20 against a normal force of 10: it slides at mu 0.5 (friction 5) and sticks at mu 3.
    #[test]
    fn friction_sticks_inside_the_cone_and_slides_on_it() {
        for (mu, sticks) in [(0.5, false), (3.0, true)] {
            let mut s = ContactSolver::default();
            let mut rows = vec![row(
                BodyPoint::vertex(0, 0),
                Counterpart::Obstacle(0),
                Vec3::y(),
                -0.1,
                Vec3::new(0.2, 0.0, 0.0),
                mu,
            )];
            s.assemble(&rows, &mut diagonal(&[0.01]));
            s.solve(&mut rows, &SolverSettings::default());
            let f = rows[0].world_force();
            assert!((f.y - 10.0).abs() < 1e-6, "{f:?}");
            if sticks {
                assert!((f.x + 20.0).abs() < 1e-6, "{f:?}");
                assert!(!rows[0].sliding);
            } else {
                assert!((f.x + 5.0).abs() < 1e-6, "{f:?}");
                assert!(rows[0].sliding);
            }
        }
    }

    /// Coupled contacts: two vertices whose compliance couples them (a stiff bar) pressed
    /// on a plane, one penetrating: the solve meets the complementarity conditions exactly.
    #[test]
    fn coupled_rows_meet_complementarity() {
        let coupled = |_b: u32, v: &[u32], out: &mut [Matrix3<f64>]| {
            let n = v.len();
            for i in 0..n {
                for j in 0..n {
                    out[i * n + j] = Matrix3::identity() * if i == j { 2.0 } else { 1.0 };
                }
            }
        };
        let mut rows = vec![
            row(
                BodyPoint::vertex(0, 0),
                Counterpart::Obstacle(0),
                Vec3::y(),
                -1.0,
                Vec3::zeros(),
                0.0,
            ),
            row(
                BodyPoint::vertex(0, 1),
                Counterpart::Obstacle(0),
                Vec3::y(),
                0.2,
                Vec3::zeros(),
                0.0,
            ),
        ];
        let mut s = ContactSolver::default();
        s.assemble(&rows, &mut { coupled });
        s.solve(&mut rows, &SolverSettings::default());
        // Only the first is active: 2 f = 1 -> f = 0.5; the second's gap 0.2 + 0.5 > 0.
        assert!((rows[0].force.x - 0.5).abs() < 1e-9);
        assert_eq!(rows[1].force.x, 0.0);
        // Both penetrate: 2 f0 + f1 = 1 and f0 + 2 f1 = 0.8 give f0 = 0.4, f1 = 0.2.
        rows[1].gap = -0.8;
        rows[0].force = Vec3::zeros();
        rows[1].force = Vec3::zeros();
        s.solve(&mut rows, &SolverSettings::default());
        assert!((rows[0].force.x - 0.4).abs() < 1e-6, "{:?}", rows[0].force);
        assert!((rows[1].force.x - 0.2).abs() < 1e-6, "{:?}", rows[1].force);
    }

    /// A frame is orthonormal, right-handed, with the normal first.
    #[test]
    fn frames_are_orthonormal() {
        for n in [
            Vec3::x(),
            Vec3::y(),
            Vec3::z(),
            Vec3::new(1.0, 2.0, -3.0).normalize(),
        ] {
            let f = frame_of(&n);
            assert!((f.transpose() * f - Matrix3::identity()).amax() < 1e-12);
            assert!((f.determinant() - 1.0).abs() < 1e-12);
            assert_eq!(f.column(0).into_owned(), n);
        }
    }
}
