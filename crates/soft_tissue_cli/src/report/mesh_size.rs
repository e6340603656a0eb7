//! Step time against mesh size, on one thread and on every core.

use super::*;

/// Step time against mesh size: the generated liver at several resolutions.
pub(super) fn mesh_size_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    resolutions: &[f64],
    quick: bool,
    threads: &soft_tissue_core::parallel::Threads,
    step: &mut dyn FnMut(&str),
) -> Res<()> {
    let steps = if quick { 20 } else { 200 };
    let rows = sweep::mesh_size(resolutions, steps, threads, step)?;
    let names: Vec<&str> = sweep::SIZE_METHODS.iter().map(|m| m.name()).collect();
    let n_all = threads.count();
    writeln!(
        md,
        "## Step time against mesh size\n\n\
         The generated liver at several resolutions (1 is the paper's mesh size) under \
         `soft-tissue bench`'s load (base held, a swinging force on the top), organ FEM \
         parameters, median of {steps} steps per method, us, on one thread / on {n_all} \
         threads (the same results; large bodies split their element loop). Cages: the box \
         and a fitted cage of about 64 vertices; their step is the cage MSD plus every surface \
         vertex.\n\n\
         | resolution | nodes | tets | surface vertices | {} |\n|---|---|---|---|{}",
        names.join(" | "),
        "---|".repeat(names.len())
    )?;
    let all_names: Vec<String> = names
        .iter()
        .map(|n| format!("{n}_{n_all}_threads"))
        .collect();
    let mut header = vec!["resolution", "nodes", "tets", "surface"];
    header.extend(names.iter().copied());
    header.extend(all_names.iter().map(String::as_str));
    let mut csv = Csv::new(&header)?;
    let mut failures = Vec::new();
    for r in &rows {
        let cells: Vec<String> = r
            .median_us
            .iter()
            .zip(&r.median_all_us)
            .map(|(a, b)| match b {
                Some(b) => format!("{} / {}", us_or_error(a), us_or_error(b)),
                None => us_or_error(a),
            })
            .collect();
        for (k, (a, b)) in r.median_us.iter().zip(&r.median_all_us).enumerate() {
            for e in [a.as_ref().err(), b.as_ref().and_then(|b| b.as_ref().err())]
                .into_iter()
                .flatten()
            {
                failures.push(format!("resolution {}, {}: {e}", r.resolution, names[k]));
            }
        }
        writeln!(
            md,
            "| {} | {} | {} | {} | {} |",
            r.resolution,
            r.nodes,
            r.tets,
            r.surface,
            cells.join(" | ")
        )?;
        let csv_cell = |v: &Result<f64, String>| match v {
            Ok(t) => t.to_string(),
            Err(e) => format!("failed: {e}"),
        };
        let mut row = cells![r.resolution, r.nodes, r.tets, r.surface].to_vec();
        row.extend(r.median_us.iter().map(csv_cell));
        row.extend(
            r.median_all_us
                .iter()
                .map(|v| v.as_ref().map_or("-".into(), csv_cell)),
        );
        csv.row(row)?;
    }
    let exponent = |all: bool| -> Vec<Option<f64>> {
        (0..names.len())
            .map(|k| sweep::growth_exponent(&rows, k, all))
            .collect()
    };
    let (exp_one, exp_all) = (exponent(false), exponent(true));
    let fmt_exp = |e: &Option<f64>| e.map_or("-".into(), |p| format!("{p:.2}"));
    writeln!(
        md,
        "| growth exponent (fit of time = a tets^p) | | | | {} |",
        exp_one
            .iter()
            .zip(&exp_all)
            .map(|(a, b)| if b.is_some() {
                format!("{} / {}", fmt_exp(a), fmt_exp(b))
            } else {
                fmt_exp(a)
            })
            .collect::<Vec<_>>()
            .join(" | ")
    )?;
    if !failures.is_empty() {
        writeln!(md, "\nFailed measurements (whole messages):\n")?;
        for f in &failures {
            writeln!(md, "- {}", f.replace(['\n', '\r'], " "))?;
        }
    }
    csv.save(out, "mesh_size.csv")?;
    // Memory of the FEM methods.
    let fem: Vec<usize> = (0..names.len())
        .filter(|&k| rows.iter().any(|r| r.matrix_bytes[k].is_some()))
        .collect();
    writeln!(
        md,
        "\nMatrices and factors held per body (values and indices), MiB: the block system, \
         rest stiffness and block Cholesky factor of linear and corotational FEM; the scalar \
         Laplacian and per-axis-pattern scalar factor of the prefactored model.\n\n\
         | resolution | tets | {} |\n|---|---|{}",
        fem.iter()
            .map(|&k| names[k])
            .collect::<Vec<_>>()
            .join(" | "),
        "---|".repeat(fem.len())
    )?;
    for r in &rows {
        writeln!(
            md,
            "| {} | {} | {} |",
            r.resolution,
            r.tets,
            fem.iter()
                .map(|&k| r.matrix_bytes[k].map_or("-".into(), |b| format!(
                    "{:.2}",
                    b as f64 / (1024.0 * 1024.0)
                )))
                .collect::<Vec<_>>()
                .join(" | ")
        )?;
    }
    let series: Vec<Series> = names
        .iter()
        .enumerate()
        .map(|(k, name)| Series {
            name: (*name).into(),
            points: rows
                .iter()
                .filter_map(|r| r.median_us[k].as_ref().ok().map(|t| (r.nodes as f64, *t)))
                .collect(),
            line: true,
            markers: true,
        })
        .collect();
    chart(
        &out.join("mesh_size.png"),
        "Step time against mesh size (generated liver, one thread)",
        Axis {
            desc: "nodes",
            log: true,
        },
        Axis {
            desc: "median step, us",
            log: true,
        },
        &series,
    )?;
    writeln!(md, "\n![step time against mesh size](mesh_size.png)\n")?;
    fn by_name<T: serde::Serialize>(
        names: &[&str],
        v: &[T],
    ) -> serde_json::Map<String, serde_json::Value> {
        names
            .iter()
            .zip(v)
            .map(|(n, e)| ((*n).to_string(), json!(e)))
            .collect()
    }
    js.insert(
        "mesh_size_growth_exponent".into(),
        json!({ "one_thread": by_name(&names, &exp_one), "all_threads": by_name(&names, &exp_all),
                "threads": n_all }),
    );
    js.insert(
        "mesh_size".into(),
        json!(
            rows.iter()
                .map(|r| json!({
                    "resolution": r.resolution, "nodes": r.nodes, "tets": r.tets,
                    "surface": r.surface,
                    "median_us": by_name(&names, &r.median_us.iter().map(time_json).collect::<Vec<_>>()),
                    "median_all_threads_us": by_name(&names, &r.median_all_us.iter()
                        .map(|v| v.as_ref().map_or(serde_json::Value::Null, time_json))
                        .collect::<Vec<_>>()),
                    "matrix_bytes": names.iter().zip(&r.matrix_bytes)
                        .map(|(n, v)| ((*n).to_string(), json!(v)))
                        .collect::<serde_json::Map<_, _>>(),
                }))
                .collect::<Vec<_>>()
        ),
    );
    Ok(())
}
