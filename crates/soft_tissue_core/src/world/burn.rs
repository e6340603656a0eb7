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
    }
}
