//! The goals the report checks, each with its measured value and a verdict.

use super::*;

/// What the goals are decided from.
pub(super) struct Inputs<'a> {
    pub best_fitted_vs_fem: &'a Option<(String, f64, f64)>,
    pub liver_cage: Option<f64>,
    pub liver_precise: Option<f64>,
    pub all_precise_step_us: f64,
    pub scaling: &'a [(usize, f64, f64)],
    pub budget: &'a [(String, crate::realtime::RunCosts)],
    pub peer_rows: &'a [peer::PeerRow],
    pub sweep_points: &'a [sweep::Point],
}

/// The "Goals" section.
pub(super) fn goals_section(md: &mut String, js: &Json, g: &Inputs<'_>) -> Res<()> {
    // Goals.
    writeln!(md, "## Goals\n")?;
    let verdict = |ok: bool| if ok { "met" } else { "**missed**" };
    if let Some((name, max, cage_us)) = g.best_fitted_vs_fem {
        let ratio = g.liver_precise.zip(g.liver_cage).map(|(p, c)| p / c);
        writeln!(
            md,
            "- Cage error below the paper's with a fitted cage (max < 4 % against FEM): best \
             fitted cage `{name}`, max {max:.2} %: {}. Cost: the liver's box-cage step (median) \
             is {} us against {} us corotational (ratio {}, goal >= 100: {}); the cylinder's \
             `{name}` cage step is {cage_us:.1} us.",
            verdict(*max < 4.0),
            us(g.liver_cage),
            us(g.liver_precise),
            ratio.map_or("-".into(), |r| format!("{r:.0}x")),
            ratio.map_or("undecided", |r| verdict(r >= 100.0)),
        )?;
    }
    // Against the MSD: the best cage of each calibration (the paper: 8.1 %, box cage).
    let fig5 = js
        .get("fig5")
        .and_then(|f| f.as_array())
        .cloned()
        .unwrap_or_default();
    let best_vs_msd = |dynamics: &str| {
        fig5.iter()
            .filter(|r| {
                r["precise"].as_str().is_some_and(|p| p.starts_with("MSD"))
                    && r["dynamics"] == dynamics
            })
            .filter_map(|r| Some((r["cage"].as_str()?.to_owned(), r["max_pct"].as_f64()?)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    };
    if let (Some((cal, cal_max)), Some((con, con_max))) =
        (best_vs_msd("calibrated"), best_vs_msd("condensed"))
    {
        writeln!(
            md,
            "- Cage error against the MSD (RK4) at most the paper's 8.1 %: best cage with the \
             default calibrated dynamics `{cal}`, max {cal_max:.2} %: {}; with the opt-in \
             condensed dynamics `{con}`, max {con_max:.2} %: {}.",
            verdict(cal_max <= 8.1),
            verdict(con_max <= 8.1),
        )?;
    }
    writeln!(
        md,
        "- All four organs at their precise level under 1 ms per step: whole step {:.1} us: {}.",
        g.all_precise_step_us,
        verdict(g.all_precise_step_us < 1000.0)
    )?;
    if let (Some(first), Some(last)) = (g.scaling.first(), g.scaling.last()) {
        writeln!(
            md,
            "- {} resting bodies plus one touched under 2x one touched alone: {:.1} us against \
             {:.1} us ({:.2}x): {}.",
            last.0,
            last.1,
            first.1,
            last.1 / first.1,
            verdict(last.1 < 2.0 * first.1)
        )?;
    }
    for (scene, c) in g.budget {
        if scene.contains("all precise") {
            let solve = c.stages.get("solve").map_or(0.0, |t| t.mean_us);
            if solve > 0.0 {
                let r = c.step.mean_us / solve;
                writeln!(
                    md,
                    "- Organs all precise: whole step at most 1.4x the sum of the solver steps: {r:.2}x: {}.",
                    verdict(r <= 1.4)
                )?;
            }
            continue;
        }
        if let Some(r) = c.worst_over_precise_median {
            writeln!(
                md,
                "- `{scene}`: largest whole step at most 3x the median of the steps with a precise body: {r:.2}x: {}.",
                verdict(r <= 3.0)
            )?;
        }
        if let Some(r) = c.contact_over_solve {
            writeln!(
                md,
                "- `{scene}`: contact (detection and the contact problem) at most half the solvers (free motion and corrections): {r:.3}: {}.",
                verdict(r <= 0.5)
            )?;
        }
        let worst = c
            .bodies
            .iter()
            .filter_map(|b| b.worst_switch_ratio.map(|r| (r, b.name.as_str())))
            .max_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((r, body)) = worst {
            writeln!(
                md,
                "- `{scene}`: every switch step at most 2x the body's median precise step: worst {r:.2}x ({body}): {}.",
                verdict(r <= 2.0)
            )?;
        }
    }
    let thread_rows = js
        .get("realtime_budget")
        .and_then(|b| b.get("threads"))
        .and_then(|t| t.as_array())
        .cloned()
        .unwrap_or_default();
    for row in &thread_rows {
        let (Some(scene), Some(n), Some(mean), Some(median), Some(same)) = (
            row["scene"].as_str(),
            row["threads"].as_u64(),
            row["speedup_mean"].as_f64(),
            row["speedup_median"].as_f64(),
            row["same_state"].as_bool(),
        ) else {
            continue;
        };
        writeln!(
            md,
            "- `{scene}` all precise at least 1.5x faster on {n} threads than on one, same \
             final state: mean {mean:.2}x, median {median:.2}x, state {}: {}.",
            if same { "identical" } else { "different" },
            verdict(same && mean >= 1.5)
        )?;
    }
    for r in g.peer_rows {
        let faster = r.ours_median_us < r.rapier_median_us;
        match &r.closed_form {
            Some(c) => writeln!(
                md,
                "- Our corotational FEM step faster than rapier3d's FEM soft body on `{}` at \
                 equal or smaller error against the closed form: {:.1} us against {:.1} us \
                 ({:.1}x); largest node distance {:.2} % against {:.2} % (mesh floor {:.2} %), \
                 end displacement {:.2} % against {:.2} % (mesh floor {:.2} %): {}.",
                r.mesh,
                r.ours_median_us,
                r.rapier_median_us,
                r.rapier_median_us / r.ours_median_us,
                c.ours_error_pct,
                c.rapier_error_pct,
                c.mesh_floor_pct,
                c.ours_tip_error_pct,
                c.rapier_tip_error_pct,
                c.floor_tip_error_pct,
                verdict(
                    faster
                        && c.ours_error_pct <= c.rapier_error_pct
                        && c.ours_tip_error_pct <= c.rapier_tip_error_pct
                )
            )?,
            None => writeln!(
                md,
                "- Our corotational FEM step faster than rapier3d's FEM soft body on `{}` (no \
                 closed form: speed only): {:.1} us against {:.1} us ({:.1}x): {}.",
                r.mesh,
                r.ours_median_us,
                r.rapier_median_us,
                r.rapier_median_us / r.ours_median_us,
                verdict(faster)
            )?,
        }
    }
    if let Some(best) = g
        .sweep_points
        .iter()
        .filter(|p| p.config.family == "cage")
        .min_by(|a, b| a.max_pct.total_cmp(&b.max_pct))
    {
        writeln!(
            md,
            "- (Context from the sweep) the most accurate cage setting against the fine \
             corotational reference: `{}`, max {:.2} %, {:.1} us per step.",
            best.config.label, best.max_pct, best.median_us
        )?;
    }
    Ok(())
}
