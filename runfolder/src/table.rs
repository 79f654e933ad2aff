//! A CSV table of a run folder as the learner writes it (`metrics.csv`, `evals.csv`: a header, then one line per
//! row, no quoting), read back by name.

use std::path::Path;

/// The largest table read (a run of many thousand epochs is a few MB).
const MAX_BYTES: u64 = 256 << 20;

/// A CSV with a header.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Table {
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// The table in `path`; an error names what is wrong (missing, too large, empty).
    pub fn read(path: &Path) -> Result<Table, String> {
        let size = std::fs::metadata(path).map_err(|e| e.to_string())?.len();
        if size > MAX_BYTES {
            return Err(format!("{size} bytes, more than the {MAX_BYTES} read"));
        }
        let text = std::fs::read_to_string(path).map_err(|e| e.to_string())?;
        Table::parse(&text)
    }

    /// The table in `text`.
    pub fn parse(text: &str) -> Result<Table, String> {
        let mut lines = text
            .lines()
            .map(|l| l.split(',').map(str::to_string).collect());
        let header = lines.next().ok_or("empty")?;
        Ok(Table {
            header,
            rows: lines.collect(),
        })
    }

    /// The rows (epochs of `metrics.csv`) of the table in `path`; 0 when it cannot be read.
    pub fn rows_in(path: &Path) -> usize {
        Table::read(path).map_or(0, |t| t.rows.len())
    }

    /// The cells of column `name`, in row order ("" where a row is short).
    pub fn column(&self, name: &str) -> Result<Vec<&str>, String> {
        let i = self
            .header
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| format!("no column {name}"))?;
        Ok(self
            .rows
            .iter()
            .map(|r| r.get(i).map_or("", String::as_str))
            .collect())
    }

    /// Column `name` parsed, each cell that does not parse as `None`.
    pub fn parsed<T: std::str::FromStr>(&self, name: &str) -> Result<Vec<Option<T>>, String> {
        Ok(self
            .column(name)?
            .into_iter()
            .map(|c| c.parse().ok())
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_column_reads_back_by_name() {
        let t = Table::parse("epoch,steps_collected,epoch_s\n0,36,0.5\n1,x,1.5\n2\n").unwrap();
        assert_eq!(t.rows.len(), 3);
        assert_eq!(t.column("epoch").unwrap(), ["0", "1", "2"]);
        assert_eq!(
            t.parsed::<u64>("steps_collected").unwrap(),
            [Some(36), None, None]
        );
        assert_eq!(
            t.parsed::<f64>("epoch_s").unwrap(),
            [Some(0.5), Some(1.5), None]
        );
        assert!(t.column("nope").unwrap_err().contains("nope"));
        assert!(Table::parse("").is_err());
    }

    #[test]
    fn a_missing_file_is_no_rows() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(Table::rows_in(&dir.path().join("metrics.csv")), 0);
        std::fs::write(dir.path().join("metrics.csv"), "a,b\n1,2\n3,4\n").unwrap();
        assert_eq!(Table::rows_in(&dir.path().join("metrics.csv")), 2);
    }
}
