//! Contact against closed forms and laws: Coulomb's incline, Hertz, Newton's third law at
//! rest, a grasp held by friction, organs at rest on a table (the cases of
//! `soft_tissue_core::contact::cases`, which the tests check).

use soft_tissue_core::contact::cases;

use super::*;

/// One contact case.
#[derive(serde::Serialize)]
struct ContactRow {
    case: String,
    setting: String,
    measured: String,
    expected: String,
    error: String,
    goal: String,
    met: bool,
}

impl ReportRow for ContactRow {
    const MD_HEAD: &'static [&'static str] = &[
        "case",
        "setting",
        "measured",
        "closed form / law",
        "error",
        "goal",
        "met",
    ];

    fn md_cells(&self) -> Vec<String> {
        vec![
            self.case.clone(),
            self.setting.clone(),
            self.measured.clone(),
            self.expected.clone(),
            self.error.clone(),
            self.goal.clone(),
            if self.met { "met" } else { "**missed**" }.into(),
        ]
    }
}

/// The contact section: every case, a row each.
pub(super) fn contact_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    quick: bool,
    step: &mut dyn FnMut(&str),
) -> Res<()> {
    writeln!(
        md,
        "## Contact against closed forms\n\n\
         Contact is solved inside the implicit step (`soft_tissue_core::contact`: each body's \
         free motion, one contact problem with Signorini and Coulomb conditions over its \
         compliance, each body's correction). Cases from `soft_tissue_core::contact::cases` \
         (the tests check the same goals):\n\n\
         - **incline**: a stiff block (corotational FEM, 0.2 x 0.1 x 0.2 m, 100 kPa) on a \
         rigid plane tilted by the angle, both surfaces with friction mu, 2.5 s at 5 ms; \
         sticking: the largest drift of its centroid after the first 0.5 s (goal 1e-3 of its \
         size); sliding: its acceleration fitted after 0.5 s against g (sin - mu cos) (goal 3 \
         %).\n\
         - **Hertz**: a rigid frictionless sphere (radius 1) pressed 0.075 into a quarter \
         block (linear FEM, E 1, nu 0.3, 16 x 16 x 16, graded from the spacing given in \
         contact radii, cells growing by the growth given), the whole block's force against 4/3 E / (1 - nu^2) sqrt(R) d^1.5 \
         (goal 10 % on the finest, falling with refinement).\n\
         - **balance**: a ball held pressed a quarter of the liver's smallest dimension into \
         the anchored liver for 20 s: the force on the tool against the anchors' reaction \
         (goal 1 %).\n\
         - **grasp**: the `grasp` scene and its `grasp-spleen` script (a spleen of 0.15 kg on \
         a table, a grasper closing on it and lifting 5 cm), the spleen's and the jaws' \
         friction mu: how far the surface the jaws held when the lift began rose (goal: at \
         least 90 % of the lift with mu 0.4, at most 20 % with mu 0.05; the centroid rises \
         less, the spleen hanging from the jaws).\n\
         - **stack**: the `stack` scene (liver, stomach and spleen dropped on a table, free, \
         under gravity) for 25 s: when every body is back at its cage, up-switches after \
         that, deepest penetration over the run (goals: settled within 15 s, none rises \
         again, penetration at most 1e-3 of the body's smallest dimension).\n"
    )?;
    let mut rows = Vec::new();
    let g = 9.81;
    let angles: &[f64] = incline_angles(quick);
    for mu in [0.3, 0.6] {
        for &angle in angles {
            step(&format!("contact: incline {angle} degrees, mu {mu}"));
            let run = cases::incline(angle, mu, 2.5)?;
            let theta = angle.to_radians();
            let setting = format!(
                "{angle} degrees, mu {mu}, penetration {:.1e}",
                run.penetration
            );
            if theta.tan() < mu {
                let drift = run.drift_after(0.5);
                rows.push(ContactRow {
                    case: "incline: sticks".into(),
                    setting,
                    measured: format!("drift {drift:.2e}"),
                    expected: "0".into(),
                    error: format!("{:.2e} of its size", drift / run.size),
                    goal: "1e-3".into(),
                    met: drift <= 1e-3 * run.size && run.penetration <= 1e-3 * run.thickness,
                });
            } else {
                let a = run.acceleration_after(0.5);
                let expected = g * (theta.sin() - mu * theta.cos());
                let error = (a - expected).abs() / expected;
                rows.push(ContactRow {
                    case: "incline: slides".into(),
                    setting,
                    measured: format!("{a:.4} m/s^2"),
                    expected: format!("{expected:.4} m/s^2"),
                    error: format!("{:.2} %", 100.0 * error),
                    goal: "3 %".into(),
                    met: error <= 0.03 && run.penetration <= 1e-3 * run.thickness,
                });
            }
        }
    }
    let meshes: &[(f64, f64)] = if quick {
        &cases::HERTZ_MESHES[..1]
    } else {
        &cases::HERTZ_MESHES
    };
    let mut last = f64::INFINITY;
    for (k, &(spacing, growth)) in meshes.iter().enumerate() {
        step(&format!("contact: Hertz, spacing {spacing}"));
        let run = cases::hertz(spacing, growth)?;
        let error = (run.force - run.hertz).abs() / run.hertz;
        let finest = k + 1 == meshes.len();
        rows.push(ContactRow {
            case: "Hertz".into(),
            setting: format!("spacing {spacing} a, growth {growth}, {} tets", run.tets),
            measured: format!("{:.5}", run.force),
            expected: format!("{:.5}", run.hertz),
            error: format!("{:.2} %", 100.0 * error),
            goal: if finest {
                "10 %, falling".into()
            } else {
                "falling".into()
            },
            met: error < last && (!finest || error <= 0.10),
        });
        last = error;
    }
    step("contact: balance at rest");
    let b = cases::balance(assets, if quick { 5.0 } else { 20.0 })?;
    let off = (b.tool - b.anchors).norm() / b.tool.norm();
    rows.push(ContactRow {
        case: "balance".into(),
        setting: format!("liver at rest (speed {:.1e} of its size / s)", b.speed),
        measured: format!("tool ({:.4}, {:.4}, {:.4})", b.tool.x, b.tool.y, b.tool.z),
        expected: format!(
            "anchors ({:.4}, {:.4}, {:.4})",
            b.anchors.x, b.anchors.y, b.anchors.z
        ),
        error: format!("{:.3} %", 100.0 * off),
        goal: "1 %".into(),
        met: off <= 0.01 && b.precise,
    });
    for (mu, hold) in [(0.4, true), (0.05, false)] {
        step(&format!("contact: grasp, mu {mu}"));
        let r = cases::grasp(mu, assets)?;
        let share = r.lifted / r.lift;
        rows.push(ContactRow {
            case: if hold { "grasp: holds" } else { "grasp: slips" }.into(),
            setting: format!(
                "mu {mu}, squeeze {:.2} N, penetration {:.1e} of its size",
                r.squeeze,
                r.penetration / r.smallest
            ),
            measured: format!(
                "held surface rose {:.1} mm (centroid {:.1} mm)",
                1000.0 * r.lifted,
                1000.0 * r.centroid_rose
            ),
            expected: format!("lift {:.0} mm", 1000.0 * r.lift),
            error: format!("{:.0} % of the lift", 100.0 * share),
            goal: if hold { ">= 90 %" } else { "<= 20 %" }.into(),
            met: (if hold { share >= 0.9 } else { share <= 0.2 })
                && r.penetration <= 1e-3 * r.smallest,
        });
    }
    step("contact: stack at rest");
    let s = cases::stack(assets, if quick { 10.0 } else { 25.0 })?;
    let worst = s.penetration.iter().copied().fold(0.0, f64::max);
    rows.push(ContactRow {
        case: "stack".into(),
        setting: format!("{} on a table", s.names.join(", ")),
        measured: match s.settled_at {
            Some(t) => format!(
                "all at their cages at {t:.2} s, {} rose after",
                s.rose_after
            ),
            None => "not all at their cages".into(),
        },
        expected: "rest".into(),
        error: format!("penetration {worst:.1e} of the size"),
        goal: "15 s, none rises, 1e-3".into(),
        met: s.settled_at.is_some_and(|t| t <= 15.0) && s.rose_after == 0 && worst <= 1e-3,
    });
    let json = write_rows(&rows, md, out, "contact.csv")?;
    writeln!(md)?;
    js.insert("contact".into(), json);
    Ok(())
}

/// The incline angles the section runs (one in the quick report).
fn incline_angles(quick: bool) -> &'static [f64] {
    if quick { &[25.0] } else { &[15.0, 25.0, 35.0] }
}

/// How many progress steps the section takes: the inclines at two mu, the Hertz meshes, the
/// balance, the grasp at two mu, the stack.
pub(super) fn steps(quick: bool) -> usize {
    let hertz = if quick { 1 } else { cases::HERTZ_MESHES.len() };
    2 * incline_angles(quick).len() + hertz + 1 + 2 + 1
}
