//! An epoch's metrics as one record, built where each number is computed (written through [`crate::sink::Sink`]).
//!
//! A metric is one line at the place that computes it (CleanRL's `writer.add_scalar(name, value)`):
//!
//! ```text
//!     record.real("imitation_loss", fit.imitation, 6);     // a real, written with 6 decimals in metrics.csv
//!     record.count("d_plus", replay.len_plus());             // a count
//!     record.flag("closed_by_timeout", collected.timed_out); // a flag
//! ```
//!
//! and nothing else: `metrics.csv` gets a column at its end, TensorBoard a scalar, the bus's JSON a field. A metric
//! not put in an epoch (a network that did not train) is an empty cell. The record goes through the port `Sink`
//! (Acme's injected logger, `logger.write(result)`, in [`crate::sink`]); the sinks are in the cabc-outputs crate.
//!
//! Checkpoints written before records existed hold each row as an object of named fields (`EpochRow`, up to
//! 2f28af3): [`rows`] reads them through [`LEGACY`], so a resumed old run writes the same `metrics.csv` byte for
//! byte.

use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::fmt;

/// One metric's value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    Count(u64),
    /// A real and the decimals `metrics.csv` writes it with (None: the shortest text that reads back exactly).
    Real(f64, Option<u8>),
    Flag(bool),
}

impl Value {
    /// The number TensorBoard plots (a flag as 0 or 1).
    pub fn as_f64(self) -> f64 {
        match self {
            Value::Count(n) => n as f64,
            Value::Real(x, _) => x,
            Value::Flag(b) => f64::from(u8::from(b)),
        }
    }
}

/// The `metrics.csv` cell.
impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Value::Count(n) => write!(f, "{n}"),
            Value::Real(x, Some(decimals)) => write!(f, "{x:.*}", decimals as usize),
            Value::Real(x, None) => write!(f, "{x}"),
            Value::Flag(b) => write!(f, "{b}"),
        }
    }
}

/// An epoch's metrics: name -> value, in the order they were put.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Record {
    entries: Vec<(String, Value)>,
}

impl Record {
    /// The record of epoch `epoch` (its first metric).
    pub fn new(epoch: u64) -> Self {
        let mut record = Record::default();
        record.count("epoch", epoch);
        record
    }

    /// Puts a metric; putting a name again replaces its value in place.
    pub fn put(&mut self, name: &str, value: Value) -> &mut Self {
        match self.entries.iter_mut().find(|(n, _)| n == name) {
            Some(entry) => entry.1 = value,
            None => self.entries.push((name.to_string(), value)),
        }
        self
    }

    pub fn count(&mut self, name: &str, n: impl TryInto<u64>) -> &mut Self {
        self.put(name, Value::Count(n.try_into().unwrap_or(u64::MAX)))
    }

    /// A real written with `decimals` decimals in `metrics.csv` (TensorBoard and the bus get every digit).
    pub fn real(&mut self, name: &str, x: f64, decimals: u8) -> &mut Self {
        self.put(name, Value::Real(x, Some(decimals)))
    }

    /// A real written as the shortest text that reads back exactly (a configuration value such as rho).
    pub fn exact(&mut self, name: &str, x: f64) -> &mut Self {
        self.put(name, Value::Real(x, None))
    }

    pub fn flag(&mut self, name: &str, b: bool) -> &mut Self {
        self.put(name, Value::Flag(b))
    }

    pub fn get(&self, name: &str) -> Option<Value> {
        self.entries.iter().find(|(n, _)| n == name).map(|e| e.1)
    }

    /// A metric as a number (a flag as 0 or 1); None when not put.
    pub fn f64(&self, name: &str) -> Option<f64> {
        self.get(name).map(Value::as_f64)
    }

    /// A count; None when not put or not a count.
    pub fn u64(&self, name: &str) -> Option<u64> {
        match self.get(name)? {
            Value::Count(n) => Some(n),
            _ => None,
        }
    }

    /// The epoch (0 for a record without one).
    pub fn epoch(&self) -> u64 {
        self.u64("epoch").unwrap_or(0)
    }

    pub fn iter(&self) -> impl Iterator<Item = (&str, Value)> {
        self.entries.iter().map(|(n, v)| (n.as_str(), *v))
    }

    /// The record as a JSON object (the bus's metrics): every digit of the reals.
    pub fn to_json(&self) -> serde_json::Value {
        let number =
            |x: f64| serde_json::Number::from_f64(x).map_or(serde_json::Value::Null, Into::into);
        self.iter()
            .map(|(name, value)| {
                let v = match value {
                    Value::Count(n) => n.into(),
                    Value::Real(x, _) => number(x),
                    Value::Flag(b) => b.into(),
                };
                (name.to_string(), v)
            })
            .collect::<serde_json::Map<_, _>>()
            .into()
    }
}

/// `name=cell` pairs, for the log.
impl fmt::Display for Record {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, (name, value)) in self.iter().enumerate() {
            write!(f, "{}{name}={value}", if i == 0 { "" } else { " " })?;
        }
        Ok(())
    }
}

/// What a column held before records, for reading old checkpoints (`EpochRow`'s fields: a missing field was its
/// default, 0 or None).
#[derive(Clone, Copy, Debug)]
pub enum Legacy {
    Count,
    OptCount,
    Real(u8),
    OptReal(u8),
    /// A real written as its shortest exact text.
    Exact,
    Flag,
    /// `incomplete_share`: incomplete_steps / max(steps_collected, 1), derived when the table was written.
    IncompleteShare,
}

/// `metrics.csv`'s columns as of 2f28af3, when a row was a struct, in their order. Frozen: `metrics.csv` keeps them
/// first, in this order (old run folders, `cabc compare` and readers by position go on working), and rows of old
/// checkpoints are read through it. A new metric is not added here: it is put where it is computed, and its column
/// comes after these, in the order new columns first appear.
pub const LEGACY: [(&str, Legacy); 34] = [
    ("epoch", Legacy::Count),
    ("beta", Legacy::Real(6)),
    ("steps_collected", Legacy::Count),
    ("steps_published", Legacy::Count),
    ("segments", Legacy::Count),
    ("steps_taken", Legacy::Count),
    ("steps_staged", Legacy::Count),
    ("incomplete_steps", Legacy::Count),
    ("incomplete_share", Legacy::IncompleteShare),
    ("d_plus", Legacy::Count),
    ("d_uncertain", Legacy::Count),
    ("d_minus", Legacy::Count),
    ("dynamics_only", Legacy::Count),
    ("autolabel_removed", Legacy::Count),
    ("rho", Legacy::Exact),
    ("imitation_loss", Legacy::Real(6)),
    ("safety_loss", Legacy::Real(6)),
    ("dynamics_loss", Legacy::OptReal(6)),
    ("critic_loss", Legacy::OptReal(6)),
    ("critic_accuracy", Legacy::OptReal(6)),
    ("critic_points", Legacy::OptCount),
    ("collect_s", Legacy::Real(3)),
    ("train_s", Legacy::Real(3)),
    ("epoch_s", Legacy::Real(3)),
    ("closed_by_timeout", Legacy::Flag),
    ("eval_version", Legacy::OptCount),
    ("eval_laps", Legacy::OptCount),
    ("critic_positives", Legacy::OptCount),
    ("critic_negatives", Legacy::OptCount),
    ("uncertain_truncating", Legacy::Count),
    ("uncertain_spawn", Legacy::Count),
    ("uncertain_patience", Legacy::Count),
    ("uncertain_failed_lap", Legacy::Count),
    ("expert_failures", Legacy::Count),
];

/// In a checkpoint, a list of entries: `[name, count]`, `[name, flag]`, `[name, real, decimals or null]`.
impl Serialize for Record {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let entries: Vec<serde_json::Value> = self
            .iter()
            .map(|(name, value)| match value {
                Value::Count(n) => serde_json::json!([name, n]),
                Value::Flag(b) => serde_json::json!([name, b]),
                Value::Real(x, decimals) => serde_json::json!([name, x, decimals]),
            })
            .collect();
        entries.serialize(s)
    }
}

/// A list of entries (an old checkpoint's rows, objects of `EpochRow`'s fields, are [`rows`]').
impl<'de> Deserialize<'de> for Record {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let entries = match serde_json::Value::deserialize(d)? {
            serde_json::Value::Array(entries) => entries,
            other => return Err(D::Error::custom(format!("a record, not {other}"))),
        };
        let mut record = Record::default();
        for entry in entries {
            let bad = || D::Error::custom(format!("a record's entry, not {entry}"));
            let parts = entry.as_array().ok_or_else(bad)?;
            let name = parts.first().and_then(|n| n.as_str()).ok_or_else(bad)?;
            let value = match parts.as_slice() {
                [_, serde_json::Value::Bool(b)] => Value::Flag(*b),
                [_, n] => Value::Count(n.as_u64().ok_or_else(bad)?),
                // serde_json writes a NaN as null.
                [_, x, decimals] => Value::Real(
                    if x.is_null() {
                        f64::NAN
                    } else {
                        x.as_f64().ok_or_else(bad)?
                    },
                    match decimals {
                        serde_json::Value::Null => None,
                        d => Some(
                            d.as_u64()
                                .and_then(|d| u8::try_from(d).ok())
                                .ok_or_else(bad)?,
                        ),
                    },
                ),
                _ => return Err(bad()),
            };
            record.put(name, value);
        }
        Ok(record)
    }
}

/// The columns of a table of `records`: [`LEGACY`]'s, then every other name in the order it first appears.
pub fn columns(records: &[Record]) -> Vec<&str> {
    let mut columns: Vec<&str> = LEGACY.iter().map(|(name, _)| *name).collect();
    for record in records {
        for (name, _) in record.iter() {
            if !columns.contains(&name) {
                columns.push(name);
            }
        }
    }
    columns
}

/// `metrics.csv`'s text: the header of [`columns`], then one line per record (an empty cell where it has no
/// such metric).
pub fn table(records: &[Record]) -> String {
    let columns = columns(records);
    let mut text = columns.join(",");
    text.push('\n');
    for record in records {
        let cells: Vec<String> = columns
            .iter()
            .map(|name| record.get(name).map(|v| v.to_string()).unwrap_or_default())
            .collect();
        text.push_str(&cells.join(","));
        text.push('\n');
    }
    text
}

/// A line of a table (`metrics.csv`, `evals.csv`) that does not read back.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("line {line}: {message}")]
pub struct TableError {
    /// The line, from 1 (the header).
    pub line: usize,
    pub message: String,
}

/// A row of [`csv_rows`]: its line number (from 1) and its cells.
pub type CsvRow<'a> = (usize, Vec<&'a str>);

/// A CSV table's header and its rows, cells trimmed, each row with its line number (from 1); blank lines are skipped,
/// and a table without a header or a row whose cells are not the header's count is refused.
pub fn csv_rows(text: &str) -> Result<(Vec<&str>, Vec<CsvRow<'_>>), TableError> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines.next().ok_or(TableError {
        line: 1,
        message: "no header (an empty table)".into(),
    })?;
    let header: Vec<&str> = header.split(',').map(str::trim).collect();
    let rows = lines
        .map(|(i, line)| {
            let cells: Vec<&str> = line.split(',').map(str::trim).collect();
            if cells.len() != header.len() {
                return Err(TableError {
                    line: i + 1,
                    message: format!(
                        "{} cells, the header has {} columns",
                        cells.len(),
                        header.len()
                    ),
                });
            }
            Ok((i + 1, cells))
        })
        .collect::<Result<_, _>>()?;
    Ok((header, rows))
}

/// [`table`]'s text read back: a record per line, a metric per non-empty cell under its column's name (a number
/// without a point a count, `true` / `false` a flag, any other number a real with the decimals it was written with),
/// so that [`table`] gives the same text again. Blank lines are skipped; a line with more or fewer cells than the
/// header, a cell that is not a number or a flag, a table without an `epoch` column or without a header are refused.
pub fn parse_table(text: &str) -> Result<Vec<Record>, TableError> {
    let (header, rows) = csv_rows(text)?;
    if !header.contains(&"epoch") {
        return Err(TableError {
            line: 1,
            message: format!("no epoch column in the header {:?}", header.join(",")),
        });
    }
    let mut records = vec![];
    for (line, cells) in rows {
        let fail = |message: String| TableError { line, message };
        let mut record = Record::default();
        for (name, cell) in header.iter().zip(cells) {
            if cell.is_empty() {
                continue;
            }
            let value = cell_value(cell)
                .ok_or_else(|| fail(format!("{name}: {cell:?} is not a number or a flag")))?;
            record.put(name, value);
        }
        if record.u64("epoch").is_none() {
            return Err(fail("no epoch (a count) in the row".into()));
        }
        records.push(record);
    }
    Ok(records)
}

/// A cell of [`table`] as the value that writes it.
fn cell_value(cell: &str) -> Option<Value> {
    match cell {
        "true" => return Some(Value::Flag(true)),
        "false" => return Some(Value::Flag(false)),
        _ => {}
    }
    if cell.bytes().all(|b| b.is_ascii_digit()) {
        if let Ok(n) = cell.parse() {
            return Some(Value::Count(n));
        }
    }
    let x: f64 = cell.parse().ok()?;
    let decimals = match cell.split_once('.') {
        Some((_, fraction)) if fraction.bytes().all(|b| b.is_ascii_digit()) => {
            u8::try_from(fraction.len()).ok()
        }
        _ => None,
    };
    Some(Value::Real(x, decimals))
}

/// `state.json`'s `rows`: each a record (a list of entries), or an old checkpoint's object of `EpochRow`'s fields.
pub(crate) fn rows<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Record>, D::Error> {
    Vec::<serde_json::Value>::deserialize(d)?
        .into_iter()
        .map(|row| match row {
            serde_json::Value::Object(row) => legacy_row(&row).map_err(D::Error::custom),
            entries => serde_json::from_value(entries).map_err(D::Error::custom),
        })
        .collect()
}

/// A row of an old checkpoint (an object of `EpochRow`'s fields), through [`LEGACY`].
fn legacy_row(row: &serde_json::Map<String, serde_json::Value>) -> Result<Record, String> {
    let mut record = Record::default();
    for (name, kind) in LEGACY {
        let field = row.get(name).filter(|v| !v.is_null());
        let count = |v: &serde_json::Value| v.as_u64().ok_or(format!("{name}: {v} is not a count"));
        // serde_json writes a NaN as null: read back as NaN.
        let real = |v: Option<&serde_json::Value>| match v {
            None => Ok(f64::NAN),
            Some(v) => v.as_f64().ok_or(format!("{name}: {v} is not a number")),
        };
        let value = match kind {
            Legacy::Count => Value::Count(field.map_or(Ok(0), count)?),
            Legacy::OptCount => match field {
                Some(v) => Value::Count(count(v)?),
                None => continue,
            },
            Legacy::Real(decimals) => Value::Real(
                if row.contains_key(name) {
                    real(field)?
                } else {
                    0.0
                },
                Some(decimals),
            ),
            Legacy::Exact => Value::Real(
                if row.contains_key(name) {
                    real(field)?
                } else {
                    0.0
                },
                None,
            ),
            Legacy::OptReal(decimals) => match field {
                Some(v) => Value::Real(real(Some(v))?, Some(decimals)),
                None => continue,
            },
            Legacy::Flag => match field {
                Some(v) => Value::Flag(v.as_bool().ok_or(format!("{name}: {v} is not a flag"))?),
                None => Value::Flag(false),
            },
            Legacy::IncompleteShare => {
                let steps = |n| record.u64(n).unwrap_or(0);
                let share =
                    steps("incomplete_steps") as f64 / steps("steps_collected").max(1) as f64;
                Value::Real(share, Some(4))
            }
        };
        record.put(name, value);
    }
    Ok(record)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_keep_their_precision_and_reals_every_digit_elsewhere() {
        let mut r = Record::new(3);
        r.real("beta", 0.123456789, 6)
            .exact("rho", 1.0 / 3.0)
            .count("d_plus", 12usize)
            .flag("closed_by_timeout", true)
            .real("beta", 0.5, 6);
        assert_eq!(
            r.to_string(),
            "epoch=3 beta=0.500000 rho=0.3333333333333333 d_plus=12 closed_by_timeout=true"
        );
        assert_eq!(r.f64("closed_by_timeout"), Some(1.0));
        assert_eq!(r.to_json()["rho"], serde_json::json!(1.0 / 3.0));
        assert_eq!(r.u64("beta"), None);
    }

    #[test]
    fn a_record_round_trips_through_a_checkpoint() {
        let mut r = Record::new(7);
        r.real("loss", 1e-9, 6)
            .real("nan", f64::NAN, 3)
            .exact("rho", 0.1)
            .count("n", u64::MAX)
            .flag("f", false);
        let text = serde_json::to_string(&r).unwrap();
        assert_eq!(
            text,
            r#"[["epoch",7],["loss",1e-9,6],["nan",null,3],["rho",0.1,null],["n",18446744073709551615],["f",false]]"#
        );
        let back: Record = serde_json::from_str(&text).unwrap();
        assert_eq!(back.to_string(), r.to_string());
        assert!(back.f64("nan").unwrap().is_nan());
        for bad in [
            r#"[["x"]]"#,
            r#"[[1, 2]]"#,
            r#"[["x", -1]]"#,
            r#"[["x", 1.0, 300]]"#,
            "3",
        ] {
            assert!(serde_json::from_str::<Record>(bad).is_err(), "{bad}");
        }
    }

    /// `metrics.csv` reads back into records that write the same text again, with the same numbers; a malformed
    /// table is refused with its line.
    #[test]
    fn a_table_reads_back() {
        let mut a = Record::new(0);
        a.real("beta", 1.0, 6)
            .exact("rho", 1.0)
            .exact("lr", 0.001)
            .real("imitation_loss", 0.153080, 6)
            .real("negative", -0.0, 6)
            .real("nan", f64::NAN, 3)
            .flag("closed_by_timeout", false)
            .count("d_plus", 1005u32);
        let mut b = Record::new(1);
        b.real("beta", 0.95, 6)
            .real("critic_loss", 0.5, 6)
            .flag("closed_by_timeout", true)
            .count("new_column", 7u32);
        let text = table(&[a, b.clone()]);
        let back = parse_table(&text).unwrap();
        assert_eq!(table(&back), text);
        assert_eq!(back.len(), 2);
        assert_eq!(back[0].f64("imitation_loss"), Some(0.15308));
        assert_eq!(back[0].f64("rho"), Some(1.0));
        assert_eq!(back[0].u64("d_plus"), Some(1005));
        assert!(back[0].f64("nan").unwrap().is_nan());
        assert_eq!(
            back[0].get("critic_loss"),
            None,
            "an empty cell is no metric"
        );
        assert_eq!(back[1], b);
        // Blank lines (a trailing one, CRLF) are no rows.
        let crlf = "epoch,loss\r\n0,0.5\r\n\r\n1,0.25\r\n";
        assert_eq!(parse_table(crlf).unwrap()[1].f64("loss"), Some(0.25));
        for (bad, line, what) in [
            ("", 1, "no header"),
            ("beta\n1.0\n", 1, "no epoch column"),
            ("epoch,loss\n0,0.5\n1\n", 3, "1 cells, the header has 2"),
            ("epoch,loss\n0,0.5,9\n", 2, "3 cells"),
            ("epoch,loss\n0,abc\n", 2, "loss: \"abc\" is not a number"),
            ("epoch,loss\n,0.5\n", 2, "no epoch"),
            ("epoch,loss\n0.5,0.5\n", 2, "no epoch"),
        ] {
            let e = parse_table(bad).unwrap_err();
            assert_eq!(e.line, line, "{bad:?}: {e}");
            assert!(e.to_string().contains(what), "{bad:?}: {e}");
        }
    }

    #[test]
    fn new_columns_come_after_the_legacy_ones_in_order_of_appearance() {
        let mut a = Record::new(0);
        a.count("zeta", 1u32);
        let mut b = Record::new(1);
        b.count("alpha", 2u32).count("zeta", 3u32);
        let text = table(&[a, b]);
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        assert_eq!(header.len(), LEGACY.len() + 2);
        assert_eq!(&header[LEGACY.len()..], ["zeta", "alpha"]);
        assert_eq!(header[..LEGACY.len()], LEGACY.map(|(n, _)| n));
        let row: Vec<&str> = lines.next().unwrap().split(',').collect();
        assert_eq!((row[0], &row[LEGACY.len()..]), ("0", &["1", ""][..]));
    }
}
