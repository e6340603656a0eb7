//! The rows of the paper's Tables II to V and of the scaling table: what each writes to
//! Markdown, CSV and JSON.

use super::*;

/// A cylinder of Tables II and III under one method pair.
#[derive(serde::Serialize)]
pub(super) struct PaperTableRow {
    pub table: &'static str,
    pub script: &'static str,
    pub method_a: &'static str,
    pub method_b: &'static str,
    pub body: String,
    pub cage_steps: u64,
    pub mean_cage_us: Option<f64>,
    pub precise_steps: u64,
    pub mean_precise_us: Option<f64>,
    pub switches: u64,
    pub worst_jump_pct: f64,
}

impl ReportRow for PaperTableRow {
    const MD_HEAD: &'static [&'static str] = &[
        "A",
        "B",
        "A cage",
        "A precise",
        "B cage",
        "B precise",
        "switches A / B",
        "worst jump A / B %",
    ];

    /// A body without its partner: the B columns empty.
    fn md_cells(&self) -> Vec<String> {
        vec![
            self.method_a.into(),
            self.method_b.into(),
            us(self.mean_cage_us),
            us(self.mean_precise_us),
            "-".into(),
            "-".into(),
            format!("{} / -", self.switches),
            format!("{:.2} / -", self.worst_jump_pct),
        ]
    }

    /// One Markdown row per method pair: its two bodies side by side, as the paper's tables.
    fn md_rows(rows: &[Self]) -> Vec<Vec<String>> {
        rows.chunks(2)
            .filter_map(|pair| match pair {
                [a, b] => Some(vec![
                    a.method_a.into(),
                    a.method_b.into(),
                    us(a.mean_cage_us),
                    us(a.mean_precise_us),
                    us(b.mean_cage_us),
                    us(b.mean_precise_us),
                    format!("{} / {}", a.switches, b.switches),
                    format!("{:.2} / {:.2}", a.worst_jump_pct, b.worst_jump_pct),
                ]),
                _ => None,
            })
            .collect()
    }
}

/// An organ of Tables IV and V: with the cage level and without it.
#[derive(serde::Serialize)]
pub(super) struct OrganTableRow {
    pub body: String,
    pub with_cage_mean_cage_us: Option<f64>,
    pub with_cage_mean_precise_us: Option<f64>,
    pub without_cage_mean_precise_us: Option<f64>,
}

impl ReportRow for OrganTableRow {
    const MD_HEAD: &'static [&'static str] = &[
        "body",
        "with cage level: cage",
        "with cage level: precise",
        "without: precise",
    ];

    fn md_cells(&self) -> Vec<String> {
        vec![
            self.body.clone(),
            us(self.with_cage_mean_cage_us),
            us(self.with_cage_mean_precise_us),
            us(self.without_cage_mean_precise_us),
        ]
    }
}

/// One touched organ and `resting` resting ones: the mean whole step, us.
#[derive(serde::Serialize)]
pub(super) struct ScalingRow {
    pub resting: usize,
    pub with_switching_us: f64,
    pub without_switching_us: f64,
}

impl ReportRow for ScalingRow {
    const MD_HEAD: &'static [&'static str] = &["N resting", "with switching", "without switching"];

    fn md_cells(&self) -> Vec<String> {
        vec![
            self.resting.to_string(),
            format!("{:.1}", self.with_switching_us),
            format!("{:.1}", self.without_switching_us),
        ]
    }
}
