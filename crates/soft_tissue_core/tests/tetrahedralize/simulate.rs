//! A meshed surface simulates: raised by a poke, back at its cage after.

use soft_tissue_core::mesh::tetrahedralize::{TetrahedralizeOptions, tetrahedralize};

use super::shapes::{ellipsoid, sphere};

/// A meshed surface simulates: in a world with the organ material, the built-in `poke`
/// raises it to its precise level and, after the withdrawal, it returns to its cage.
#[test]
fn a_meshed_surface_rises_under_a_poke_and_returns_to_its_cage() {
    let (mesh, r) = tetrahedralize(&sphere(0.5), &TetrahedralizeOptions::default()).unwrap();
    assert!(!r.graded);
    poke_rises_and_returns(mesh);
}

/// The same with a graded mesh (the lens): its coarsened boundary simulates as well.
#[test]
fn a_graded_mesh_rises_under_a_poke_and_returns_to_its_cage() {
    let (mesh, r) =
        tetrahedralize(&ellipsoid(1.0, 0.6, 0.1), &TetrahedralizeOptions::default()).unwrap();
    assert!(r.graded);
    poke_rises_and_returns(mesh);
}

fn poke_rises_and_returns(mesh: soft_tissue_core::mesh::TetMesh) {
    use soft_tissue_core::contact::{ContactConfig, Tool};
    use soft_tissue_core::precision::{BodySettings, Level};
    use soft_tissue_core::scenario::{Anchor, CYLINDER_MSD, ORGAN_FEM};
    use soft_tissue_core::world::{Script, ScriptAction, SoftTissueWorld, WorldBody, WorldConfig};
    let dt = ORGAN_FEM.dt;
    let mut settings = BodySettings::new(ORGAN_FEM.params, CYLINDER_MSD.params, dt);
    settings.boundary = Anchor::SoftToRest { stiffness: 1.0 }.boundary(&mesh);
    let mut world = SoftTissueWorld::new(WorldConfig {
        dt,
        contact: ContactConfig::for_scale(mesh.bbox().smallest_dimension()),
    })
    .unwrap();
    let body = WorldBody::new("sphere", std::sync::Arc::new(mesh), settings, None).unwrap();
    world.add_body(body).unwrap();
    let script = Script::builtin("poke", &world).unwrap();
    let tool = world.add_tool(Tool::new("tool", script.tool).unwrap());
    let (mut rose, mut precise_at_end) = (false, true);
    for k in 1..=800 {
        let t = k as f64 * dt;
        let (p, a) = script.pose_at(t);
        let tl = &mut world.tools_mut()[tool];
        tl.set_pose(p, a).unwrap();
        for e in script.events_in(t - dt, t) {
            if let ScriptAction::Cautery(w) = e.action {
                tl.set_cautery(w).unwrap();
            }
        }
        world.step_fixed().unwrap();
        let level = world.bodies()[0].model().level();
        rose |= level == Level::Precise;
        precise_at_end = level == Level::Precise;
    }
    assert!(rose, "the poke raised the meshed sphere");
    assert!(!precise_at_end, "it returned to its cage");
    let last = world.bodies()[0].model().last_switch().unwrap();
    assert!(last.jump_ratio < 0.005, "{last:?}");
}
