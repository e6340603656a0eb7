//! Speed against error: every method and cage on the liver against a fine reference.

use super::*;

/// Speed against error: every level and setting against a fine-step corotational reference.
pub(super) fn speed_error_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    configs: &[sweep::Config],
    duration: f64,
    step: &mut dyn FnMut(&str),
) -> Res<Vec<sweep::Point>> {
    let scene = load_scene("organs", assets)?;
    let (reference, points) =
        sweep::speed_against_error(&scene, assets, "poke-liver", configs, duration, step)?;
    writeln!(
        md,
        "## Speed against error\n\n\
         The organs under `poke-liver` for {duration} s, every body held at one level with one \
         setting; the liver's nodes against the {} (CG tolerance 1e-8) at the same times. \
         Time: the liver's median step (its heat field included), us. Error: mean and largest \
         node distance, % of the liver's smallest dimension. The cages are calibrated against \
         corotational FEM unless marked `paper` (the paper's cage MSD). `MSD` keeps the scene's \
         constant spring stiffness (the paper's); `MSD ... material` fits its springs to the \
         liver's FEM material. A setting is on the Pareto front when no other is both faster \
         and more accurate (largest distance).\n\n\
         The reference's own convergence: the same run at half its step ({}) is {:.4} % away \
         at most ({:.5} % mean).\n",
        reference.config.label,
        reference.halved,
        reference.halving_max_pct,
        reference.halving_mean_pct,
    )?;
    let mut sorted: Vec<&sweep::Point> = points.iter().collect();
    sorted.sort_by(|a, b| a.median_us.total_cmp(&b.median_us));
    let rows: Vec<SpeedErrorRow> = sorted
        .iter()
        .map(|p| SpeedErrorRow {
            setting: p.config.label.clone(),
            family: p.config.family,
            dt: p.config.dt,
            median_us: p.median_us,
            mean_pct: p.mean_pct,
            max_pct: p.max_pct,
            pareto: p.pareto,
        })
        .collect();
    let rows_json = write_rows(&rows, md, out, "speed_error.csv")?;
    let mut families: Vec<&str> = Vec::new();
    for p in &points {
        if !families.contains(&p.config.family) {
            families.push(p.config.family);
        }
    }
    let mut series: Vec<Series> = families
        .iter()
        .map(|f| Series {
            name: (*f).into(),
            points: points
                .iter()
                .filter(|p| p.config.family == *f)
                .map(|p| (p.median_us, p.max_pct))
                .collect(),
            line: false,
            markers: true,
        })
        .collect();
    let mut front: Vec<(f64, f64)> = sorted
        .iter()
        .filter(|p| p.pareto)
        .map(|p| (p.median_us, p.max_pct))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    series.push(Series {
        name: "Pareto front".into(),
        points: front,
        line: true,
        markers: false,
    });
    chart(
        &out.join("speed_error.png"),
        "Speed against error (organs, poke-liver, the liver)",
        Axis {
            desc: "median step, us",
            log: true,
        },
        Axis {
            desc: "largest node distance to the reference, %",
            log: true,
        },
        &series,
    )?;
    writeln!(md, "\n![speed against error](speed_error.png)\n")?;
    js.insert(
        "speed_error".into(),
        json!({
            "reference": reference.config.label,
            "reference_halved": reference.halved,
            "reference_halving_max_pct": reference.halving_max_pct,
            "reference_halving_mean_pct": reference.halving_mean_pct,
            "points": rows_json,
        }),
    );
    Ok(points)
}

/// One setting of the sweep: its cost and its error against the reference.
#[derive(serde::Serialize)]
struct SpeedErrorRow {
    setting: String,
    family: &'static str,
    dt: f64,
    median_us: f64,
    mean_pct: f64,
    max_pct: f64,
    pareto: bool,
}

impl ReportRow for SpeedErrorRow {
    const MD_HEAD: &'static [&'static str] = &["setting", "step us", "mean %", "max %", "Pareto"];

    fn md_cells(&self) -> Vec<String> {
        vec![
            self.setting.clone(),
            format!("{:.1}", self.median_us),
            format!("{:.3}", self.mean_pct),
            format!("{:.3}", self.max_pct),
            if self.pareto { "yes" } else { "" }.into(),
        ]
    }
}
