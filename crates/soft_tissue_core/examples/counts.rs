//! scratch
use soft_tissue_core::mesh::generate::*;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let h: f64 = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(0.2);
    for o in [Organ::Cylinder].into_iter().chain(Organ::ORGANS) {
        if args.len() > 1 && args[1] != o.name() && args[1] != "all" {
            continue;
        }
        let t = std::time::Instant::now();
        let m = stuff(&o.shape(), h).unwrap();
        let q = m.quality();
        let (pn, pt, ps) = o.paper_counts();
        println!(
            "{:9} h={h} nodes {:5} ({:+.0}%) tets {:5} ({:+.0}%) tris {:5} ({:+.0}%) surfverts {} mindih {:.1} maxdih {:.1} comps {} bbox {:?} {:?}",
            o.name(),
            m.node_count(),
            100.0 * (m.node_count() as f64 / pn as f64 - 1.0),
            m.tet_count(),
            100.0 * (m.tet_count() as f64 / pt as f64 - 1.0),
            m.surface().triangles().len(),
            100.0 * (m.surface().triangles().len() as f64 / ps as f64 - 1.0),
            m.surface().vertices().len(),
            q.min_dihedral_deg,
            q.max_dihedral_deg,
            m.component_count(),
            m.bbox().extent().as_slice(),
            t.elapsed()
        );
    }
}
