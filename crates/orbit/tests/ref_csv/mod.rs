//! A small reader for the reference CSV files in `tests/data/` (RFC 4180 quoting, columns by
//! name). Test-only: panics with the file, row and column on malformed data.

#![allow(dead_code, clippy::unwrap_used)]

/// A parsed CSV file.
pub struct Csv {
    name: &'static str,
    header: Vec<String>,
    /// The data rows.
    pub rows: Vec<Vec<String>>,
}

fn split_line(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut field = String::new();
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                field.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => out.push(std::mem::take(&mut field)),
            _ => field.push(c),
        }
    }
    out.push(field);
    out
}

impl Csv {
    /// Parse `text` (the contents of `tests/data/<name>`).
    pub fn parse(name: &'static str, text: &str) -> Csv {
        let mut lines = text.lines().filter(|l| !l.trim().is_empty());
        let header = split_line(lines.next().unwrap_or(""));
        let rows: Vec<Vec<String>> = lines.map(split_line).collect();
        for (i, r) in rows.iter().enumerate() {
            assert_eq!(
                r.len(),
                header.len(),
                "{name}: row {} has {} fields",
                i + 2,
                r.len()
            );
        }
        Csv { name, header, rows }
    }

    /// Index of a column.
    pub fn col(&self, column: &str) -> usize {
        self.header
            .iter()
            .position(|h| h == column)
            .unwrap_or_else(|| panic!("{}: no column {column}", self.name))
    }

    /// A text field.
    pub fn s<'a>(&self, row: &'a [String], column: &str) -> &'a str {
        &row[self.col(column)]
    }

    /// A numeric field.
    pub fn f(&self, row: &[String], column: &str) -> f64 {
        let t = self.s(row, column);
        t.parse()
            .unwrap_or_else(|_| panic!("{}: column {column}: not a number: {t:?}", self.name))
    }

    /// A vector from `<prefix>x<suffix>`, `..y..`, `..z..` columns.
    pub fn v3(&self, row: &[String], prefix: &str, suffix: &str) -> nalgebra::Vector3<f64> {
        nalgebra::Vector3::new(
            self.f(row, &format!("{prefix}x{suffix}")),
            self.f(row, &format!("{prefix}y{suffix}")),
            self.f(row, &format!("{prefix}z{suffix}")),
        )
    }
}
