//! Tissue an electrode vaporized leaves the body: the ball of each crater is carved out of
//! the mesh ([`crate::mesh::cut::carve`]) by the same topology change as a cut
//! ([`WorldBody::begin_vaporize`]).

use super::*;
use crate::mesh::cut::Ball;

/// A body's heat after a carve that left it one piece (`cut_job.rs`): `field`, built for
/// the new `mesh` with `old`'s coarse temperatures (without the spots), takes `old`'s
/// spots, each standing at the new mesh's node nearest its centre (the nodes about it were
/// carved away), so the electrode's millimetre field goes on through the carve instead of
/// being handed to the nodes and started again. The carved balls count as tried (the
/// caller), so a crater is carved again only once it has grown by [`CARVE_GROWTH`].
pub(super) fn carry_spots(field: &mut HeatField, mesh: &TetMesh, old: &HeatField) {
    let x = mesh.positions();
    // The field finds the nearest node among those about the spot; a scan of every node
    // only for a spot with none within its reach.
    field.carry_spots_from(old, |centre| {
        let nearest = (0..x.len())
            .min_by(|&a, &b| (x[a] - centre).norm().total_cmp(&(x[b] - centre).norm()))
            .unwrap_or(0);
        vec![(nearest as u32, 1.0)]
    });
}

/// Where an electrode's sub-grid field is measured for its tissue fraction, in electrode
/// radii from its centre (the distances its closed-form check uses).
pub const FRACTION_RADII: [f64; 3] = [1.5, 2.0, 3.0];

/// The share of an electrode's surroundings that is tissue: of the spheres at
/// [`FRACTION_RADII`] electrode radii (`radius`, scene units) about `centre` on the rest
/// mesh, the part inside it ([`crate::mesh::occupancy::sphere_share_inside`]): about 1/2 on a
/// flat surface, 1/4 on a right-angled edge, more at the floor of a crater. Kept within
/// [1/8, 1] (a centre off the mesh still heats the tissue it touches).
pub fn tissue_fraction(mesh: &crate::mesh::TetMesh, centre: &Vec3, radius: f64) -> f64 {
    let radii = FRACTION_RADII.map(|k| k * radius);
    crate::mesh::occupancy::sphere_share_inside(mesh, centre, &radii).clamp(0.125, 1.0)
}

/// [`tissue_fraction`] with `occupancy`'s grid of the mesh's tetrahedra (built at its first
/// question about `mesh`), so a step that starts a spot neither scans the mesh nor
/// allocates: the same number.
pub fn tissue_fraction_in(
    occupancy: &mut crate::mesh::occupancy::Occupancy,
    mesh: &Arc<crate::mesh::TetMesh>,
    centre: &Vec3,
    radius: f64,
) -> f64 {
    let radii = FRACTION_RADII.map(|k| k * radius);
    occupancy
        .sphere_share_inside(mesh, centre, &radii)
        .clamp(0.125, 1.0)
}

/// A crater is carved again (after a carve that did not land) once its ball has grown by this
/// factor.
pub const CARVE_GROWTH: f64 = 1.25;

impl WorldBody {
    /// The balls of tissue electrodes vaporized, to carve out (rest shape, scene units; see
    /// [`crate::heat::HeatField::vaporized_balls`]): those at least as large as their
    /// electrode, and [`CARVE_GROWTH`] times one tried before at the same place. Empty
    /// without heat or craters (cheap then: no allocation).
    pub fn vaporized(&self) -> Vec<Ball> {
        self.to_carve().collect()
    }

    /// Whether [`WorldBody::vaporized`] has a ball (without allocating: the cut stage asks
    /// every step while a crater exists).
    pub fn has_vaporized(&self) -> bool {
        self.to_carve().next().is_some()
    }

    /// The balls of [`WorldBody::vaporized`], one by one.
    fn to_carve(&self) -> impl Iterator<Item = Ball> + '_ {
        let heat = self.heat.as_ref().filter(|h| h.has_craters());
        let s = heat.map_or(1.0, |h| h.params().meters_per_unit);
        heat.into_iter()
            .flat_map(|h| h.vaporized_balls_iter())
            .map(move |(centre, r, electrode)| {
                (
                    Ball {
                        centre,
                        radius: r / s,
                    },
                    electrode / s,
                )
            })
            .filter(|(b, electrode)| {
                let tried = self
                    .vaporize_tried
                    .iter()
                    .filter(|t| t.centre == b.centre)
                    .map(|t| t.radius)
                    .fold(0.0, f64::max);
                b.radius >= electrode.max(CARVE_GROWTH * tried)
            })
            .map(|(b, _)| b)
    }

    /// Notes that carving `balls` was tried and did not land (each is tried again once it
    /// has grown by [`CARVE_GROWTH`]).
    pub fn vaporize_refused(&mut self, balls: &[Ball]) {
        self.vaporize_tried.extend_from_slice(balls);
        self.prune_vaporize_tried();
    }

    /// Keeps of the balls tried (refused, or carved: a carve that landed adds its balls)
    /// only what [`WorldBody::vaporized`] still compares with: the largest at the centre of
    /// each crater there is now. A crater whose spot ended matches no ball any more, and a
    /// smaller ball tried at a centre is outgrown by the larger one. In place, without
    /// allocating; the list stays as long as the craters are many.
    pub(crate) fn prune_vaporize_tried(&mut self) {
        let tried = &mut self.vaporize_tried;
        if tried.is_empty() {
            return;
        }
        let heat = self.heat.as_ref();
        let crater_at = |c: &Vec3| {
            heat.is_some_and(|h| h.vaporized_balls_iter().any(|(centre, _, _)| centre == *c))
        };
        let mut kept = 0;
        for k in 0..tried.len() {
            let ball = tried[k];
            if !crater_at(&ball.centre) {
                continue;
            }
            match tried[..kept].iter_mut().find(|t| t.centre == ball.centre) {
                Some(t) => t.radius = t.radius.max(ball.radius),
                None => {
                    tried[kept] = ball;
                    kept += 1;
                }
            }
        }
        tried.truncate(kept);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boundary::Boundary;
    use crate::contact::ToolShape;
    use crate::material::{FemParams, MsdParams};
    use crate::mesh::generate::block;

    const DT: f64 = 1.0 / 64.0;
    const RADIUS: f64 = 1e-3;

    /// A block of liver 8 mm across meshed at 1 mm, fixed below, with a 1 mm spherical
    /// electrode at 30 W pressed 0.3 mm into the middle of its top.
    fn pressed_block() -> SoftTissueWorld {
        let side = 0.008;
        let mesh = block(Vec3::zeros(), Vec3::repeat(side), [8, 8, 8]).unwrap();
        let fem = FemParams {
            young_modulus: 2.0e4,
            poisson_ratio: 0.45,
            mass: 1079.0 * mesh.volume(),
            damping: 1.0,
        };
        let msd = MsdParams {
            stiffness: 100.0,
            mass: fem.mass,
            damping: 0.1,
        };
        let mut s = BodySettings::new(fem, msd, DT);
        s.boundary = Boundary::fixed_below(mesh.positions(), 1, 0.01);
        let heat = HeatParams {
            meters_per_unit: 1.0,
            ..HeatParams::liver()
        };
        let body = WorldBody::new(
            "block",
            Arc::new(mesh),
            s,
            Some((heat, HeatBoundary::insulated())),
        )
        .unwrap();
        let mut w = SoftTissueWorld::new(WorldConfig {
            dt: DT,
            contact: crate::contact::ContactConfig::for_scale(side),
        })
        .unwrap();
        w.add_body(body).unwrap();
        let t = w.add_tool(Tool::new("electrode", ToolShape::Sphere { radius: RADIUS }).unwrap());
        let tool = &mut w.tools_mut()[t];
        tool.set_electrode_radius(Some(RADIUS)).unwrap();
        tool.set_position(Vec3::new(0.5 * side, side + 0.7 * RADIUS, 0.5 * side))
            .unwrap();
        tool.set_cautery(30.0).unwrap();
        w
    }

    /// The centres of the body's craters now.
    fn craters(b: &WorldBody) -> Vec<Vec3> {
        b.heat()
            .map(|h| h.vaporized_balls_iter().map(|c| c.0).collect())
            .unwrap_or_default()
    }

    /// The balls tried are kept for the craters there are, one (the largest) at each, while
    /// an electrode sinking 1 mm/s into a block carves its craters; a refused ball is
    /// carved once it has grown by `CARVE_GROWTH`. Before, every carve and every refusal
    /// added a ball for good.
    #[test]
    fn the_balls_tried_stay_one_per_crater() {
        let mut w = pressed_block();
        let start = w.tools()[0].position();
        let mut carves = 0;
        for k in 0..128 {
            let sunk = start - Vec3::y() * 1e-3 * (k as f64 * DT);
            w.tools_mut()[0].set_position(sunk).unwrap();
            let mesh = Arc::as_ptr(w.bodies()[0].mesh());
            w.step_fixed().unwrap();
            carves += usize::from(Arc::as_ptr(w.bodies()[0].mesh()) != mesh);
            let b = &w.bodies()[0];
            let at = craters(b);
            let tried = &b.vaporize_tried;
            for (i, t) in tried.iter().enumerate() {
                assert!(at.contains(&t.centre), "step {k}: {t:?} matches no crater");
                assert!(
                    tried[..i].iter().all(|u| u.centre != t.centre),
                    "step {k}: two balls tried at one crater: {tried:?}"
                );
            }
        }
        let b = &mut w.bodies_mut()[0];
        println!(
            "{carves} carves; {} craters, {} balls tried",
            craters(b).len(),
            b.vaporize_tried.len()
        );
        assert!(carves >= 2, "{carves} carves");
        // Refusals, again and again: one ball at the crater, the largest (the rule compares
        // with it, whichever came last), and none where no crater is.
        let (centre, now, electrode) = b
            .heat()
            .unwrap()
            .vaporized_balls_iter()
            .max_by(|x, y| x.1.total_cmp(&y.1))
            .expect("a crater");
        assert!(now >= electrode);
        let big = Ball {
            centre,
            radius: now / CARVE_GROWTH * 1.01,
        };
        let small = Ball {
            centre,
            radius: now / CARVE_GROWTH * 0.99,
        };
        let gone = Ball {
            centre: centre + Vec3::x(),
            radius: now,
        };
        b.vaporize_tried.clear();
        for _ in 0..10 {
            b.vaporize_refused(&[big, gone]);
            b.vaporize_refused(&[small]);
        }
        assert_eq!(b.vaporize_tried, vec![big]);
        let here = |b: &WorldBody| b.vaporized().into_iter().find(|v| v.centre == centre);
        assert_eq!(here(b), None, "carved before it grew by CARVE_GROWTH");
        b.vaporize_tried = vec![small];
        assert_eq!(here(b).map(|v| v.radius), Some(now));
    }
}
