//! Tissue an electrode vaporized leaves the body: the tetrahedra wholly inside a crater of
//! its heat field's spots are removed by the same topology change as a cut
//! ([`SimBody::begin_vaporize`]).

use super::*;

impl SimBody {
    /// The tetrahedra wholly inside a crater an electrode vaporized (every corner, on the
    /// rest mesh, within the crater's radius of its spot's centre): tissue to remove. Empty
    /// without heat or craters, and when the same number was tried before and refused.
    pub fn vaporized_tets(&self) -> Vec<u32> {
        let Some(h) = self.heat.as_ref() else {
            return Vec::new();
        };
        let craters = h.craters();
        if craters.is_empty() {
            return Vec::new();
        }
        let s = h.params().meters_per_unit;
        let p = self.mesh.positions();
        let inside = |t: &[u32; 4]| {
            craters
                .iter()
                .any(|(c, r)| t.iter().all(|&v| (p[v as usize] - c).norm() * s <= *r))
        };
        let tets: Vec<u32> = self
            .mesh
            .tets()
            .iter()
            .enumerate()
            .filter(|(_, t)| inside(t))
            .map(|(i, _)| i as u32)
            .collect();
        if tets.len() <= self.vaporize_tried {
            return Vec::new();
        }
        tets
    }

    /// Notes that removing `count` vaporized tetrahedra was tried and did not land (it is
    /// tried again only once more are vaporized).
    pub fn vaporize_refused(&mut self, count: usize) {
        self.vaporize_tried = self.vaporize_tried.max(count);
    }
}
