//! Opt-in calibrations of a leveled model's cage beyond the default projection.
//!
//! [`condense_cage`] replaces a body's calibrated cage dynamics (the Galerkin projection of
//! its precise model, [`crate::cage::ReducedModel::project`]) by the static condensation of
//! [`crate::cage::condense`]: the same cage, with the stiffness the precise model shows
//! through the cage's coordinates. Measured in the report's Fig. 5 (cylinders, `poke-a`):
//! against the RK4 MSD it brings every cage's largest error from 12.8-15.9 % to 2-4.5 %;
//! against corotational FEM it raises it (box 7.0 to 13.6 %), so it is not the default.

use std::sync::Arc;

use crate::Vec3;
use crate::cage::CageError;
use crate::cage::condense::{CondenseOperators, condensed_model};
use crate::precision::{LeveledModel, PrecisionError};

/// Condenses `body`'s calibrated cage dynamics (see the module docs), linearised where the
/// cage's points stand at rest, as the projection was. Errors: the body's cage is not
/// calibrated ([`crate::cage::CageDynamics::Paper`]), or the condensation fails (a free
/// body, too many nodes; [`condensed_model`]). The projection comes back (and this is
/// undone) when the body settles or changes its precise method or materials.
pub fn condense_cage(body: &mut LeveledModel) -> Result<(), PrecisionError> {
    let Some(model) = body.cage().reduced().cloned() else {
        return Err(PrecisionError::Cage(CageError::InvalidArgument {
            field: "cage dynamics",
            message: "condensation replaces calibrated dynamics; this cage runs the paper's \
                      cage MSD"
                .into(),
        }));
    };
    let coords = body.cage().coordinates().clone();
    let cage = body.cage().cage().clone();
    let x = coords.rest_points().to_vec();
    let condensed = {
        let precise = body.precise();
        let (masses, fixed) = (precise.masses(), precise.fixed());
        type Mul<'a> = Box<dyn FnMut(&[Vec3], &mut [Vec3]) + 'a>;
        let (mut mul, damping): (Mul<'_>, (f64, f64, f64)) = if let Some(f) = body.fem() {
            let k = f.stiffness_at(&x, f.model());
            let c = f.config();
            (
                Box::new(move |u: &[Vec3], out: &mut [Vec3]| k.mul(u, out)),
                (c.mass_damping, c.stiffness_damping, 0.0),
            )
        } else if let Some(m) = body.msd() {
            // K u by central differences of the spring, volume and anchor forces.
            let size = x
                .iter()
                .fold((x[0], x[0]), |(lo, hi), p| (lo.inf(p), hi.sup(p)));
            let size = (size.1 - size.0).norm();
            let n = x.len();
            let (mut xp, mut fp, mut fm) =
                (x.clone(), vec![Vec3::zeros(); n], vec![Vec3::zeros(); n]);
            let x = &x;
            (
                Box::new(move |u: &[Vec3], out: &mut [Vec3]| {
                    let umax = u.iter().map(|v| v.amax()).fold(0.0, f64::max);
                    if umax == 0.0 {
                        out.fill(Vec3::zeros());
                        return;
                    }
                    let eps = 1e-6 * size / umax;
                    for ((p, x0), ui) in xp.iter_mut().zip(x).zip(u) {
                        *p = x0 + ui * eps;
                    }
                    m.spring_forces(&xp, &mut fp);
                    for ((p, x0), ui) in xp.iter_mut().zip(x).zip(u) {
                        *p = x0 - ui * eps;
                    }
                    m.spring_forces(&xp, &mut fm);
                    for ((o, a), b) in out.iter_mut().zip(&fp).zip(&fm) {
                        *o = (b - a) / (2.0 * eps);
                    }
                }),
                (0.0, 0.0, m.config().damping),
            )
        } else {
            return Err(PrecisionError::Cage(CageError::InvalidArgument {
                field: "precise model",
                message: "neither FEM nor MSD".into(),
            }));
        };
        condensed_model(
            &cage,
            &coords,
            &model,
            CondenseOperators {
                masses,
                fixed,
                stiffness: &mut *mul,
                damping,
            },
        )?
    };
    let dt = body.settings().dt;
    body.cage_mut().set_reduced(Some(Arc::new(condensed)), dt)?;
    Ok(())
}
