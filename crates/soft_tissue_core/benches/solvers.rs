//! Criterion benchmarks of one step of each method (precise and cage level) on the paper's meshes, under the
//! same load as `soft-tissue bench` (bottom fixed, a swinging force on the top).
//!
//! Run: `cargo bench -p soft_tissue_core --bench solvers`.

use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use soft_tissue_core::bench::{BenchBody, BenchMethod};
use soft_tissue_core::mesh::io::read_tet_mesh;
use soft_tissue_core::scenario::{CYLINDER_FEM, CYLINDER_MSD, ORGAN_FEM};

fn solvers(c: &mut Criterion) {
    let assets = concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets/meshes");
    for (name, fem) in [("cylinder", CYLINDER_FEM), ("liver", ORGAN_FEM)] {
        let mesh = read_tet_mesh(Path::new(assets).join(format!("{name}.vtk")))
            .expect("committed asset")
            .mesh;
        let mut group = c.benchmark_group(format!("step/{name}"));
        for method in BenchMethod::ALL {
            let mut body = BenchBody::new(
                &mesh,
                method,
                (&fem.params, fem.dt),
                (&CYLINDER_MSD.params, CYLINDER_MSD.dt),
                false,
                64,
            )
            .expect("paper parameters build");
            for _ in 0..100 {
                body.step().expect("warm-up step");
            }
            group.bench_function(method.name(), |b| b.iter(|| body.step().expect("step")));
        }
        group.finish();
    }
}

criterion_group!(benches, solvers);
criterion_main!(benches);
