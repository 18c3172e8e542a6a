//! End-to-end tests live in `tests/tests/`; this library holds what they
//! share: [`measure`], which writes a figure a test measured to the
//! measurements file that `./test.sh` gathers (`target/measurements.json`)
//! and `tools/claims.py` holds the README and the book to.

use std::io::Write;

/// Appends one measurement, `{"key", "value", "unit", "source"}`, as a JSON
/// line to the file named by `$FC_MEASUREMENTS`; does nothing when it is
/// unset (a plain `cargo test`). `source` names the check that measured it.
/// One `write` of one line on a file opened for appending: tests running in
/// parallel do not interleave their lines.
///
/// # Panics
///
/// If the file is named but cannot be written: a figure that a check should
/// have written and did not is a failed check.
pub fn measure(key: &str, value: f64, unit: &str, source: &str) {
    let Some(path) = std::env::var_os("FC_MEASUREMENTS") else {
        return;
    };
    let esc = |s: &str| s.replace('\\', "\\\\").replace('"', "\\\"");
    assert!(value.is_finite(), "measurement {key} is {value}");
    let line = format!(
        "{{\"key\":\"{}\",\"value\":{value},\"unit\":\"{}\",\"source\":\"{}\"}}\n",
        esc(key),
        esc(unit),
        esc(source)
    );
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .and_then(|mut f| f.write_all(line.as_bytes()))
        .unwrap_or_else(|e| panic!("writing {key} to {}: {e}", path.to_string_lossy()));
}
