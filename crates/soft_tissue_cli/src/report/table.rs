//! Writing the report's tables and files: CSV through the `csv` crate.

use super::*;

/// A CSV table built in memory by the `csv` crate, so every file the report writes quotes
/// the same way (RFC 4180: a field holding a comma, a quote or a line break is put in quotes,
/// its quotes doubled).
pub(crate) struct Csv(csv::Writer<Vec<u8>>);

impl Csv {
    /// A table with its header row.
    pub(crate) fn new(header: &[&str]) -> Res<Self> {
        let mut w = csv::WriterBuilder::new()
            .terminator(csv::Terminator::Any(b'\n'))
            .from_writer(Vec::new());
        w.write_record(header)?;
        Ok(Csv(w))
    }

    /// One row; each cell is written with its `Display`.
    pub(crate) fn row<I>(&mut self, cells: I) -> Res<()>
    where
        I: IntoIterator,
        I::Item: std::fmt::Display,
    {
        self.0
            .write_record(cells.into_iter().map(|c| c.to_string()))?;
        Ok(())
    }

    /// Writes the table to `dir/name`.
    pub(crate) fn save(self, dir: &Path, name: &str) -> Res<()> {
        let bytes = self.0.into_inner().map_err(|e| e.to_string())?;
        write_file(dir, name, &String::from_utf8(bytes)?)
    }
}

/// A row of cells of mixed types, each written with its `Display`.
macro_rules! cells {
    ($($c:expr),* $(,)?) => { [$(($c).to_string()),*] };
}
pub(crate) use cells;

pub(crate) fn write_file(dir: &Path, name: &str, text: &str) -> Res<()> {
    let path = dir.join(name);
    std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(())
}

/// A row of one of the report's tables: its fields are the CSV columns and the JSON keys
/// (serde, in field order), and it writes its own Markdown cells, so a section builds its
/// rows once and [`write_rows`] writes all three.
pub(crate) trait ReportRow: serde::Serialize {
    /// The Markdown table's column heads.
    const MD_HEAD: &'static [&'static str];

    /// This row's Markdown cells, one per head.
    fn md_cells(&self) -> Vec<String>;

    /// The Markdown rows of `rows` (one per row unless a table groups them).
    fn md_rows(rows: &[Self]) -> Vec<Vec<String>>
    where
        Self: Sized,
    {
        rows.iter().map(Self::md_cells).collect()
    }
}

/// The Markdown table of `rows`, head and rule included.
pub(crate) fn md_table<R: ReportRow>(rows: &[R]) -> String {
    let mut t = format!(
        "| {} |\n|{}\n",
        R::MD_HEAD.join(" | "),
        "---|".repeat(R::MD_HEAD.len())
    );
    for cells in R::md_rows(rows) {
        debug_assert_eq!(cells.len(), R::MD_HEAD.len(), "one cell per head");
        t.push_str(&format!("| {} |\n", cells.join(" | ")));
    }
    t
}

/// The rows as CSV (header from the fields' names; `None` is an empty field).
pub(crate) fn csv_text<R: ReportRow>(rows: &[R]) -> Res<String> {
    let mut w = csv::WriterBuilder::new()
        .terminator(csv::Terminator::Any(b'\n'))
        .from_writer(Vec::new());
    for r in rows {
        w.serialize(r)?;
    }
    let bytes = w.into_inner().map_err(|e| e.to_string())?;
    Ok(String::from_utf8(bytes)?)
}

/// Writes `rows` three ways: their Markdown table appended to `md`, `dir/csv_name`, and
/// their JSON (returned, for the section's entry in `report.json`).
pub(crate) fn write_rows<R: ReportRow>(
    rows: &[R],
    md: &mut String,
    dir: &Path,
    csv_name: &str,
) -> Res<serde_json::Value> {
    md.push_str(&md_table(rows));
    write_file(dir, csv_name, &csv_text(rows)?)?;
    Ok(serde_json::to_value(rows)?)
}
