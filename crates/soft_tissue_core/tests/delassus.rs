//! The contact problem's assembly against the definition of its operator, written out here
//! independently: for rows `c` and `d`, `W_cd = F_c^T (sum over the terms of c and d on one
//! body of s_i s_j w_i w_j C_b(v_i, v_j)) F_d`, with `F` the rows' frames, `s` the side's
//! sign (+ for side `a`, - for a body counterpart), `w` the points' weights and `C_b` the
//! body's compliance between two of its vertices. Rows on several bodies, vertices and
//! triangles, tools and obstacles, shuffled so rows of one body are not contiguous.

use nalgebra::{Matrix3, Vector3};
use soft_tissue_core::Vec3;
use soft_tissue_core::contact::{BodyPoint, ContactRow, ContactSolver, Counterpart};

/// A small deterministic generator (no dependency): uniform in [0, 1).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn below(&mut self, n: u32) -> u32 {
        ((self.next() * n as f64) as u32).min(n - 1)
    }
    fn unit(&mut self) -> Vec3 {
        loop {
            let v = Vec3::new(
                2.0 * self.next() - 1.0,
                2.0 * self.next() - 1.0,
                2.0 * self.next() - 1.0,
            );
            let n = v.norm();
            if n > 0.1 && n <= 1.0 {
                return v / n;
            }
        }
    }
}

const BODIES: u32 = 3;
const VERTICES: u32 = 12;

/// A symmetric positive definite compliance per body: `C_b(i, j) = sum_k P_bk(i) P_bk(j)^T
/// + delta_ij (b + 1) I`, with fixed pseudo-random 3x3 factors `P`.
fn compliance_block(b: u32, i: u32, j: u32) -> Matrix3<f64> {
    let factor = |v: u32, k: u32| {
        let mut g = Lcg(1 + 1000 * b as u64 + 37 * v as u64 + 7919 * k as u64);
        for _ in 0..3 {
            g.next();
        }
        Matrix3::from_fn(|_, _| g.next() - 0.5)
    };
    let mut c = Matrix3::zeros();
    for k in 0..2 {
        c += factor(i, k) * factor(j, k).transpose();
    }
    if i == j {
        c += Matrix3::identity() * (b as f64 + 1.0);
    }
    c
}

fn point(g: &mut Lcg, body: u32) -> BodyPoint {
    if g.next() < 0.5 {
        BodyPoint::vertex(body, g.below(VERTICES))
    } else {
        // Three distinct vertices, weights summing to one.
        let a = g.below(VERTICES);
        let b = (a + 1 + g.below(VERTICES - 1)) % VERTICES;
        let mut c = g.below(VERTICES);
        while c == a || c == b {
            c = (c + 1) % VERTICES;
        }
        let (u, v) = (g.next(), g.next());
        let (u, v) = if u + v > 1.0 {
            (1.0 - u, 1.0 - v)
        } else {
            (u, v)
        };
        BodyPoint::triangle(body, [a, b, c], [u, v, 1.0 - u - v])
    }
}

fn random_rows(g: &mut Lcg, n: usize) -> Vec<ContactRow> {
    (0..n)
        .map(|_| {
            let body = g.below(BODIES);
            let other = match g.below(3) {
                0 => {
                    let other = (body + 1 + g.below(BODIES - 1)) % BODIES;
                    Counterpart::Body(point(g, other))
                }
                1 => Counterpart::Tool { tool: 0, part: 0 },
                _ => Counterpart::Obstacle(0),
            };
            let n = g.unit();
            if g.next() < 0.2 {
                ContactRow::attachment([0; 9], point(g, body), other, Vec3::zeros())
            } else {
                ContactRow::contact(
                    [0; 9],
                    point(g, body),
                    other,
                    n,
                    0.0,
                    Vec3::zeros(),
                    0.5,
                    0.4,
                )
            }
        })
        .collect()
}

/// A row's terms on each body: (body, vertex, signed weight).
fn terms(row: &ContactRow) -> Vec<(u32, u32, f64)> {
    let mut t: Vec<_> = row.a.terms().map(|(v, w)| (row.a.body, v, w)).collect();
    if let Counterpart::Body(p) = &row.other {
        t.extend(p.terms().map(|(v, w)| (p.body, v, -w)));
    }
    t
}

/// `W_cd` from its definition.
fn reference_block(rows: &[ContactRow], c: usize, d: usize) -> Matrix3<f64> {
    let mut g = Matrix3::zeros();
    for (bc, vc, wc) in terms(&rows[c]) {
        for (bd, vd, wd) in terms(&rows[d]) {
            if bc == bd {
                g += compliance_block(bc, vc, vd) * (wc * wd);
            }
        }
    }
    rows[c].frame.transpose() * g * rows[d].frame
}

fn shares_a_body(a: &ContactRow, b: &ContactRow) -> bool {
    terms(a)
        .iter()
        .any(|(x, ..)| terms(b).iter().any(|(y, ..)| x == y))
}

#[test]
fn every_assembled_block_is_the_operator_of_its_definition() {
    let mut g = Lcg(42);
    let mut solver = ContactSolver::default();
    let mut compliance = |b: u32, vertices: &[u32], out: &mut [Matrix3<f64>]| {
        let n = vertices.len();
        for (i, &vi) in vertices.iter().enumerate() {
            for (j, &vj) in vertices.iter().enumerate() {
                out[i * n + j] = compliance_block(b, vi, vj);
            }
        }
    };
    // Several sizes, assembled one after the other into the same workspaces (a later, smaller
    // problem must not see an earlier one's blocks).
    for n in [40, 7, 1, 25] {
        let rows = random_rows(&mut g, n);
        solver.assemble(&rows, &mut compliance);
        let mut worst: f64 = 0.0;
        for c in 0..n {
            for d in 0..n {
                let want = reference_block(&rows, c, d);
                match solver.block(c, d) {
                    Some(got) => {
                        worst = worst.max((got - want).amax() / (1.0 + want.amax()));
                    }
                    None => {
                        assert!(
                            !shares_a_body(&rows[c], &rows[d]),
                            "rows {c} and {d} share a body but have no block"
                        );
                    }
                }
            }
        }
        println!("{n} rows: largest relative difference {worst:.2e}");
        assert!(worst < 1e-12, "{n} rows: {worst:e}");
    }
}

#[test]
fn applied_forces_are_the_rows_forces_summed_per_vertex() {
    let mut g = Lcg(7);
    let mut solver = ContactSolver::default();
    let mut compliance = |b: u32, vertices: &[u32], out: &mut [Matrix3<f64>]| {
        let n = vertices.len();
        for (i, &vi) in vertices.iter().enumerate() {
            for (j, &vj) in vertices.iter().enumerate() {
                out[i * n + j] = compliance_block(b, vi, vj);
            }
        }
    };
    let mut rows = random_rows(&mut g, 30);
    solver.assemble(&rows, &mut compliance);
    for r in rows.iter_mut() {
        r.force = Vector3::new(g.next(), g.next() - 0.5, g.next() - 0.5);
        r.applied = Vector3::new(0.0, g.next() - 0.5, 0.0) * 0.1;
    }
    // By definition: each term gets the row's world force still to apply times its signed
    // weight.
    let mut want = vec![vec![Vec3::zeros(); VERTICES as usize]; BODIES as usize];
    for r in &rows {
        let f = r.frame * (r.force - r.applied);
        for (b, v, w) in terms(r) {
            want[b as usize][v as usize] += f * w;
        }
    }
    let mut got = vec![vec![Vec3::zeros(); VERTICES as usize]; BODIES as usize];
    let mut seen = vec![vec![0u32; VERTICES as usize]; BODIES as usize];
    solver.apply(&mut rows, &mut |b, forces| {
        assert!(
            forces.windows(2).all(|w| w[0].0 < w[1].0),
            "vertices once each, in order"
        );
        for &(v, f) in forces {
            got[b as usize][v as usize] += f;
            seen[b as usize][v as usize] += 1;
        }
    });
    for b in 0..BODIES as usize {
        for v in 0..VERTICES as usize {
            assert!(seen[b][v] <= 1);
            assert!(
                (got[b][v] - want[b][v]).amax() < 1e-12,
                "body {b} vertex {v}: {:?} against {:?}",
                got[b][v],
                want[b][v]
            );
        }
    }
    assert!(rows.iter().all(|r| r.applied == r.force));
}
