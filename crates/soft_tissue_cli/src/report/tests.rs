//! Unit tests of the report's writers and sentences.

use super::*;

fn out_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "soft-tissue-report-test-{name}-{}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn read_back(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let mut r = csv::Reader::from_path(path).unwrap();
    let header = r.headers().unwrap().iter().map(String::from).collect();
    let rows = r
        .records()
        .map(|rec| rec.unwrap().iter().map(String::from).collect())
        .collect();
    (header, rows)
}

/// A cell with a comma, a quote and a line break comes back whole from a real CSV
/// parser, the other columns in place.
#[test]
fn csv_cells_with_commas_and_quotes_read_back_intact() {
    let dir = out_dir("csv");
    let name = "a \"quoted\", name\nover two lines";
    let mut csv = Csv::new(&["name", "value", "flag"]).unwrap();
    csv.row(cells![name, 1.5, true]).unwrap();
    csv.row(cells!["plain", -2, false]).unwrap();
    csv.save(&dir, "t.csv").unwrap();
    let (header, rows) = read_back(&dir.join("t.csv"));
    assert_eq!(header, ["name", "value", "flag"]);
    assert_eq!(rows.len(), 2);
    assert_eq!(rows[0], [name, "1.5", "true"]);
    assert_eq!(rows[1], ["plain", "-2", "false"]);
    std::fs::remove_dir_all(dir).ok();
}

/// `stability.csv` keeps its columns for a case whose name has a comma and a quote (the
/// hard cases' own names have commas: "dt 3x its limit, refuse"); it used to be written
/// with the name unquoted, one column too many.
#[test]
fn stability_csv_keeps_its_columns_for_names_with_commas_and_quotes() {
    let dir = out_dir("stability");
    let mut case = HardCase::all()
        .into_iter()
        .find(|c| c.name == "dt 3x its limit, refuse")
        .expect("the refusing RK4 case");
    case.name = "dt 3x its \"limit\", refuse";
    let assets = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"));
    let (mut md, mut js) = (String::new(), Json::new());
    stability_section(&mut md, &mut js, &dir, assets, &[case], true, &mut |_| {}).unwrap();
    let (header, rows) = read_back(&dir.join("stability.csv"));
    assert_eq!(header.len(), 11);
    assert_eq!(header[0], "case");
    assert_eq!(header[3], "outcome");
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0].len(), 11);
    assert_eq!(rows[0][0], "dt 3x its \"limit\", refuse");
    assert_eq!(rows[0][1], "MSD RK4");
    assert!(rows[0][3].starts_with("refused"), "{}", rows[0][3]);
    assert!(rows[0][4].parse::<usize>().is_ok(), "steps: {}", rows[0][4]);
    std::fs::remove_dir_all(dir).ok();
}

/// A measurement that failed shows a short form of its error in the table, the whole
/// message in the JSON (it used to be a bare "-").
#[test]
fn a_failed_measurement_shows_its_error() {
    let long = "matrix not positive definite at degree of freedom 12 (node 4, axis 0): the \
                body may lack constraints against rigid motion | or a parameter is bad";
    let cell = us_or_error(&Err(long.to_string()));
    assert!(
        cell.starts_with("failed: matrix not positive definite"),
        "{cell}"
    );
    assert!(cell.ends_with("..."), "{cell}");
    assert!(cell.len() < 80 && !cell.contains('|'), "{cell}");
    assert_eq!(us_or_error(&Ok(12.345)), "12.3");
    assert_eq!(time_json(&Err(long.to_string()))["error"], long);
    assert_eq!(time_json(&Ok(2.5)), json!(2.5));
}

/// The header's spread sentence states the repeats it was given and their ratio.
#[test]
fn the_spread_sentence_states_the_measured_ratio() {
    let s = spread_sentence(&[100.0, 110.0, 105.0], true);
    assert!(s.contains("100.0 / 110.0 / 105.0 us"), "{s}");
    assert!(s.contains("largest over smallest 1.10 (10 %)"), "{s}");
    assert!(s.contains("3 times"), "{s}");
}
