//! Meshing to a distance rather than a count: the mesh is refined until the boundary lies
//! within a given share of the bounding box's diagonal of the surface both ways (and the
//! volume within [`AIMED_VOLUME`]), up to a cap. Before any meshing, the walls' thickness
//! ([`wall_thickness`]) says what spacing and count a thin wall needs. Where the median
//! wall needs more than the start count (a thin-walled surface: a coarser lattice cannot
//! follow the wall, and the graded levels at a count far too small for it cost minutes to
//! miss), the search meshes at the median wall's spacing directly, uniform, one lattice
//! (coarser where the cap asks); elsewhere (thin only in places: a sharp rim, a tip) it
//! grows the count, the graded mesh of each count following the surface.

use super::thickness::{WallThickness, wall_thickness};
use super::{
    AIMED_VOLUME, TetrahedralizeError, TetrahedralizeOptions, TetrahedralizeReport, bounds, repair,
    tetrahedralize,
};
use crate::mesh::TetMesh;
use crate::mesh::generate::GenerateError;
use crate::mesh::io::SurfaceMesh;

/// What to mesh to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistanceGoal {
    /// The largest distance wanted between the mesh's boundary and the surface, both ways,
    /// as a fraction of the surface's bounding-box diagonal (0.01: 1 %).
    pub max_distance: f64,
    /// The smallest count tried (default 1500).
    pub start_tets: usize,
    /// The largest count asked for (default 100000): a try whose count, asked or estimated
    /// (from the walls, or from the last try at a spacing), would pass it is not made, and the
    /// search stops and says so. A try at a spacing may make more than its estimate.
    pub max_tets: usize,
    /// Smallest dihedral angle kept, degrees (default 8).
    pub min_dihedral_deg: f64,
}

impl Default for DistanceGoal {
    fn default() -> Self {
        DistanceGoal {
            max_distance: 0.01,
            start_tets: 1500,
            max_tets: 100_000,
            min_dihedral_deg: 8.0,
        }
    }
}

/// One mesh of the search.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct DistanceTry {
    /// The count asked for (`None` where a spacing was).
    pub target_tets: Option<usize>,
    /// The lattice spacing asked for (`None` where a count was).
    pub spacing: Option<f64>,
    /// The tetrahedra it gave.
    pub tets: usize,
    /// The larger of its two distances to the surface, as a fraction of the diagonal.
    pub distance: f64,
    /// Its volume against the enclosed one, as a signed fraction.
    pub volume: f64,
}

/// The walls of a surface, measured before meshing, and what they ask of the lattice.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct WallAdvice {
    /// The thickness measured.
    pub walls: WallThickness,
    /// The surface's bounding-box diagonal.
    pub bbox_diagonal: f64,
    /// The volume the surface encloses.
    pub enclosed_volume: f64,
    /// The surface's area (the parts not buried in another).
    pub area: f64,
    /// The lattice spacing that follows the thin walls (one spacing across them).
    pub spacing: f64,
    /// About how many tetrahedra a uniform lattice at that spacing gives
    /// ([`WallAdvice::tets_at`]).
    pub tets: usize,
}

impl WallAdvice {
    /// About how many tetrahedra a uniform lattice of spacing `h` gives: five per lattice
    /// cube of the volume and of a layer half a spacing deep along the surface (measured
    /// within a factor of about 1.3 on a thin-walled cup).
    pub fn tets_at(&self, h: f64) -> usize {
        let n = 5.0 * (self.enclosed_volume + 0.5 * self.area * h) / h.powi(3);
        if n.is_finite() && n < 1e12 {
            n.round() as usize
        } else {
            usize::MAX
        }
    }

    /// The advice in words.
    pub fn describe(&self) -> String {
        format!(
            "walls as thin as {:.4} ({:.2} % of the diagonal) over 5 % of the surface's area \
             (median {:.4}): a lattice spacing of about {:.4} follows them, about {} \
             tetrahedra",
            self.walls.thin,
            100.0 * self.walls.thin / self.bbox_diagonal,
            self.walls.median,
            self.spacing,
            self.tets
        )
    }
}

/// Measures `surface`'s walls (a repair and one inscribed-ball probe per triangle: seconds
/// for tens of thousands of triangles) and the spacing and count that follow them. On a
/// faceted curved surface the balls come out smaller than the smooth shape's (facets lie
/// at different depths: a 48 x 24 grid sphere's median is 0.66 of its diameter); on
/// parallel walls they are the walls' thickness.
pub fn wall_advice(surface: &SurfaceMesh) -> Result<Option<WallAdvice>, TetrahedralizeError> {
    let s = repair(surface)?;
    let outer: Vec<[u32; 3]> = if s.buried.is_empty() {
        s.triangles.clone()
    } else {
        s.triangles
            .iter()
            .zip(&s.buried)
            .filter(|&(_, &b)| b < 1.0)
            .map(|(t, _)| *t)
            .collect()
    };
    let tree = crate::mesh::surface_tree::SurfaceTree::new(&s.positions, &outer);
    let Some(walls) = wall_thickness(&s.positions, &outer, &tree) else {
        return Ok(None);
    };
    let (lo, hi) = bounds(&s.positions);
    let area: f64 = outer
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| s.positions[v as usize]);
            0.5 * (b - a).cross(&(c - a)).norm()
        })
        .sum();
    let mut advice = WallAdvice {
        walls,
        bbox_diagonal: (hi - lo).norm(),
        enclosed_volume: s.enclosed_volume,
        area,
        spacing: walls.thin,
        tets: 0,
    };
    advice.tets = advice.tets_at(advice.spacing);
    Ok(Some(advice))
}

/// What [`tetrahedralize_to_distance`] found.
#[derive(Debug)]
pub struct DistanceSearch {
    /// The kept mesh: the first within the goal, else the nearest the surface.
    pub mesh: TetMesh,
    /// Its report.
    pub report: TetrahedralizeReport,
    /// Every mesh tried, in order.
    pub tries: Vec<DistanceTry>,
    /// Whether the kept mesh lies within the distance and the volume aimed at.
    pub reached: bool,
    /// The walls, measured first (`None` for a surface without an area).
    pub advice: Option<WallAdvice>,
    /// The goal.
    pub goal: DistanceGoal,
}

impl DistanceSearch {
    /// What the search missed, in words (the cap reached, the distance and volume of the
    /// kept mesh, the walls' advice); `None` where it reached the goal.
    pub fn shortfall(&self) -> Option<String> {
        if self.reached {
            return None;
        }
        let best = self.tries.iter().find(|t| t.tets == self.report.tets);
        let mut text = format!(
            "stopped at the cap of {} tetrahedra: the kept mesh ({} tetrahedra) lies up to \
             {:.2} % of the diagonal from the surface (aimed at {:.2} %), volume {:+.2} %",
            self.goal.max_tets,
            self.report.tets,
            100.0 * best.map_or(f64::NAN, |t| t.distance),
            100.0 * self.goal.max_distance,
            100.0 * best.map_or(f64::NAN, |t| t.volume),
        );
        if let Some(a) = &self.advice {
            text += &format!("; {}", a.describe());
        }
        Some(text)
    }
}

/// Meshes `surface` finer and finer until the boundary lies within `goal.max_distance` of
/// the diagonal both ways and the volume within [`AIMED_VOLUME`] (see the module docs).
/// Where the median wall's count ([`wall_advice`], [`WallAdvice::tets_at`]) is above
/// `goal.start_tets`, it meshes at that wall's spacing (or the spacing whose count the cap
/// allows), then at finer spacings by
/// the square root of the distance's excess (between a half and 0.8 of the last), while
/// the count allows. Elsewhere it starts at `goal.start_tets` and multiplies the count by
/// 1.2 (d / goal)^1.25 (a chord's distance falls with the spacing squared, the count grows
/// as about the spacing to the -2.5), at least 1.5 and at most 8 times, up to the cap,
/// which is tried last. `on_advice` sees the walls' advice before the first mesh
/// (seconds), `on_try` each mesh as it is made (a caller can print them as they come).
pub fn tetrahedralize_to_distance(
    surface: &SurfaceMesh,
    goal: &DistanceGoal,
    on_advice: &mut dyn FnMut(&WallAdvice),
    on_try: &mut dyn FnMut(&DistanceTry),
) -> Result<DistanceSearch, TetrahedralizeError> {
    if !(goal.max_distance.is_finite() && goal.max_distance > 0.0) {
        return Err(TetrahedralizeError::Options(format!(
            "the distance must be positive, found {}",
            goal.max_distance
        )));
    }
    if goal.start_tets == 0 || goal.max_tets < goal.start_tets {
        return Err(TetrahedralizeError::Options(format!(
            "the counts must satisfy 1 <= start ({}) <= cap ({})",
            goal.start_tets, goal.max_tets
        )));
    }
    let advice = wall_advice(surface)?;
    if let Some(a) = &advice {
        on_advice(a);
    }
    // Thin-walled (half the area or more thinner than the start count can follow): by
    // spacing, from the median wall's (or the finest the cap allows: the count estimate
    // grows as the spacing to the -3). Thin in places only (a sharp rim, a tip): by count,
    // the graded mesh following them.
    let mut ask = match advice {
        Some(a) if a.tets_at(a.walls.median) > goal.start_tets => {
            let over = (a.tets_at(a.walls.median) as f64 / goal.max_tets as f64).max(1.0);
            Ask::Spacing(a.walls.median * over.cbrt())
        }
        _ => Ask::Count(goal.start_tets),
    };
    let mut tries = Vec::new();
    let mut best: Option<(TetMesh, TetrahedralizeReport, f64)> = None;
    let mut reached = false;
    let mut halvings = 0;
    loop {
        let options = TetrahedralizeOptions {
            edge_length: match ask {
                Ask::Spacing(h) => Some(h),
                Ask::Count(_) => None,
            },
            target_tets: match ask {
                Ask::Count(n) => Some(n),
                Ask::Spacing(_) => None,
            },
            min_dihedral_deg: goal.min_dihedral_deg,
        };
        let (mesh, r) = match (tetrahedralize(surface, &options), ask) {
            // A spacing thicker than the walls leaves no lattice tetrahedron inside: half
            // of it (as the count's passes do, up to 256 times finer).
            (Err(TetrahedralizeError::Generate(GenerateError::Empty(_))), Ask::Spacing(h))
                if halvings < 8 =>
            {
                halvings += 1;
                ask = Ask::Spacing(h / 2.0);
                continue;
            }
            (result, _) => result?,
        };
        let t = DistanceTry {
            target_tets: options.target_tets,
            spacing: options.edge_length,
            tets: r.tets,
            distance: r.mesh_to_surface.max(r.surface_to_mesh) / r.bbox_diagonal,
            volume: r.volume / r.enclosed_volume - 1.0,
        };
        tries.push(t);
        on_try(&t);
        let ok = t.distance <= goal.max_distance && t.volume.abs() <= AIMED_VOLUME;
        if ok || best.as_ref().is_none_or(|b| t.distance < b.2) {
            best = Some((mesh, r, t.distance));
        }
        if ok {
            reached = true;
            break;
        }
        ask = match ask {
            Ask::Count(n) => {
                if n >= goal.max_tets {
                    break;
                }
                let growth = (1.2 * (t.distance / goal.max_distance).powf(1.25)).clamp(1.5, 8.0);
                Ask::Count(((n as f64 * growth).round() as usize).min(goal.max_tets))
            }
            Ask::Spacing(h) => {
                // Finer by the square root of the distance's excess (between a half and 0.8
                // of the last), while the count it would give, from the last's, stays under
                // the cap.
                let excess = (t.distance / goal.max_distance).max(1.0);
                let factor = excess.sqrt().recip().clamp(0.5, 0.8);
                let next = h * factor;
                if t.tets as f64 * factor.powi(-3) > goal.max_tets as f64 {
                    break;
                }
                Ask::Spacing(next)
            }
        };
    }
    let (mesh, report, _) = best.expect("at least one try");
    Ok(DistanceSearch {
        mesh,
        report,
        tries,
        reached,
        advice,
        goal: *goal,
    })
}

/// What a try asks the mesher for.
#[derive(Clone, Copy)]
enum Ask {
    Count(usize),
    Spacing(f64),
}
