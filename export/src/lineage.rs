//! What the replay does not keep and the export derives: which piece of trajectory a step belongs to (episode and
//! frame), and which policy version collected it.
//!
//! * **Episodes.** A store holds its steps in the order the learner added them (a segment's steps contiguous, the
//!   segments of an epoch in (actor, incarnation, seq) order), until random eviction overwrites slots of a full store
//!   or auto-labelling compacts D?. An episode here is a maximal run of consecutive slots of one store (and one
//!   label, D- or D?) in which each step's state is, bit for bit, the previous step's next state: a segment, or
//!   several segments of one environment that followed each other (the laps of one drive). A reset, another
//!   environment's segment or an overwritten slot starts a new one.
//! * **Policy versions.** The version an epoch publishes is its number, and `metrics.csv` gives each store's size at
//!   the end of every epoch. While a store has only grown by appending (nothing evicted, nothing auto-labelled away
//!   or moved in), slot i was filled in the first epoch whose size exceeds i: the version published in that epoch
//!   (a carried-over episode's first steps were driven by the previous version). Otherwise the version is unknown,
//!   -1, for every slot of that store.

use super::ExportError;
use cabc_proto::messages::STATE_DIM;
use std::io::BufRead;
use std::path::Path;

/// Where a row comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Label {
    Plus,
    /// In D? and not (or no longer) in D-: not yet labelled.
    Uncertain,
    /// In D? and in D-: left unsafe by the last auto-labelling (the critic's negatives).
    Minus,
    DynamicsOnly,
}

impl Label {
    pub fn name(self) -> &'static str {
        match self {
            Label::Plus => "D+",
            Label::Uncertain => "D?",
            Label::Minus => "D-",
            Label::DynamicsOnly => "dynamics-only",
        }
    }
}

/// Whether two states are the same bits (a step's next state and the following step's state).
pub fn same_state(a: &[f32; STATE_DIM], b: &[f32; STATE_DIM]) -> bool {
    a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// The sizes of the stores at the end of each epoch, from `metrics.csv`.
#[derive(Clone, Debug, Default)]
pub struct EpochSizes {
    /// (epoch, |D+|, |D?|, |dynamics-only|), in file order, a re-run epoch's last row kept.
    rows: Vec<(u64, [usize; 3])>,
    /// Whether any auto-labelling removed D? points (moved into the dynamics-only store).
    removed_any: bool,
}

/// Largest `metrics.csv` read (a run of 100,000 epochs is about 30 MB).
const MAX_METRICS_BYTES: u64 = 256 << 20;

impl EpochSizes {
    /// Reads `metrics.csv` (columns found by name); `None` when the file does not exist.
    pub fn read(path: &Path) -> Result<Option<Self>, ExportError> {
        let file = match std::fs::File::open(path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(ExportError::io(path, e)),
        };
        let len = file.metadata().map_err(|e| ExportError::io(path, e))?.len();
        if len > MAX_METRICS_BYTES {
            return Err(ExportError::Metrics {
                path: path.to_path_buf(),
                line: 0,
                message: format!("{len} bytes, more than the {MAX_METRICS_BYTES} read"),
            });
        }
        let bad = |line: usize, message: String| ExportError::Metrics {
            path: path.to_path_buf(),
            line,
            message,
        };
        let mut lines = std::io::BufReader::new(file).lines();
        let header = match lines.next() {
            Some(h) => h.map_err(|e| ExportError::io(path, e))?,
            None => return Err(bad(1, "empty file".into())),
        };
        let names: Vec<&str> = header.split(',').collect();
        let column = |name: &str| {
            names
                .iter()
                .position(|n| *n == name)
                .ok_or_else(|| bad(1, format!("no column {name}")))
        };
        let epoch = column("epoch")?;
        let stores = [
            column("d_plus")?,
            column("d_uncertain")?,
            column("dynamics_only")?,
        ];
        let removed = column("autolabel_removed")?;
        let mut sizes = EpochSizes::default();
        for (i, line) in lines.enumerate() {
            let line = line.map_err(|e| ExportError::io(path, e))?;
            let cells: Vec<&str> = line.split(',').collect();
            let cell = |c: usize| -> Result<u64, ExportError> {
                let text = cells.get(c).copied().unwrap_or("");
                text.parse().map_err(|_| {
                    bad(
                        i + 2,
                        format!("{:?} in column {} is not a count", text, names[c]),
                    )
                })
            };
            let row = (
                cell(epoch)?,
                [
                    cell(stores[0])? as usize,
                    cell(stores[1])? as usize,
                    cell(stores[2])? as usize,
                ],
            );
            sizes.removed_any |= cell(removed)? > 0;
            // A resumed run may repeat an epoch: its last row is the one the replay continued from.
            sizes.rows.retain(|(e, _)| *e < row.0);
            sizes.rows.push(row);
        }
        Ok(Some(sizes))
    }
}

/// Slot -> policy version of one store: the end-of-epoch sizes while it only grew, or nothing (unknown).
#[derive(Clone, Debug, Default)]
pub struct Versions {
    /// (epoch, size at its end), sizes non-decreasing.
    growth: Option<Vec<(u64, usize)>>,
}

impl Versions {
    /// The versions of store `which` (0: D+, 1: D?, 2: dynamics-only) holding `len` steps of the `added` ever added
    /// to it, and whether D? points were ever moved into it.
    pub fn of(sizes: Option<&EpochSizes>, which: usize, len: usize, added: usize) -> Self {
        if len == 0 {
            return Versions {
                growth: Some(Vec::new()),
            };
        }
        let Some(sizes) = sizes else {
            return Versions::default();
        };
        // Evicted, removed or moved-in steps break the slot order.
        let moved_in = which == 2 && sizes.removed_any;
        if added != len || moved_in {
            return Versions::default();
        }
        let growth: Vec<(u64, usize)> = sizes.rows.iter().map(|(e, s)| (*e, s[which])).collect();
        // The checkpoint may be an epoch behind metrics.csv (a live run, or a crash between the two): the last row
        // whose size is the store's.
        let Some(last) = growth.iter().rposition(|(_, s)| *s == len) else {
            return Versions::default();
        };
        let growth = growth[..=last].to_vec();
        if growth.windows(2).any(|w| w[1].1 < w[0].1) {
            return Versions::default();
        }
        Versions {
            growth: Some(growth),
        }
    }

    pub fn known(&self) -> bool {
        self.growth.is_some()
    }

    /// The version that collected slot `slot`, -1 when unknown.
    pub fn at(&self, slot: usize) -> i64 {
        let Some(growth) = &self.growth else {
            return -1;
        };
        let i = growth.partition_point(|(_, size)| *size <= slot);
        growth.get(i).map_or(-1, |(epoch, _)| *epoch as i64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sizes(rows: &[(u64, [usize; 3])], removed_any: bool) -> EpochSizes {
        EpochSizes {
            rows: rows.to_vec(),
            removed_any,
        }
    }

    #[test]
    fn versions_follow_the_growth_of_a_store() {
        let s = sizes(&[(0, [3, 1, 0]), (1, [3, 2, 0]), (2, [7, 2, 0])], false);
        let v = Versions::of(Some(&s), 0, 7, 7);
        let got: Vec<i64> = (0..8).map(|i| v.at(i)).collect();
        assert_eq!(got, [0, 0, 0, 2, 2, 2, 2, -1]);
        // Evictions (more added than held), a size that fell, or no metrics: unknown.
        assert!(!Versions::of(Some(&s), 0, 7, 9).known());
        assert!(!Versions::of(
            Some(&sizes(&[(0, [3, 0, 0]), (1, [2, 0, 0])], false)),
            0,
            2,
            2
        )
        .known());
        assert!(!Versions::of(None, 0, 7, 7).known());
        // Points moved in by auto-labelling break the dynamics-only store's order.
        assert!(!Versions::of(Some(&sizes(&[(0, [0, 0, 4])], true)), 2, 4, 4).known());
        // The checkpoint one epoch behind metrics.csv.
        let ahead = sizes(&[(0, [3, 0, 0]), (1, [5, 0, 0])], false);
        assert_eq!(Versions::of(Some(&ahead), 0, 3, 3).at(2), 0);
    }

    #[test]
    fn metrics_rows_of_a_re_run_epoch_replace_the_earlier_ones() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.csv");
        std::fs::write(
            &path,
            "epoch,d_plus,d_uncertain,dynamics_only,autolabel_removed\n0,1,0,0,0\n1,2,0,0,0\n1,3,0,0,0\n",
        )
        .unwrap();
        let s = EpochSizes::read(&path).unwrap().unwrap();
        assert_eq!(s.rows, [(0, [1, 0, 0]), (1, [3, 0, 0])]);
        std::fs::write(&path, "epoch,d_plus\n0,1\n").unwrap();
        assert!(matches!(
            EpochSizes::read(&path),
            Err(ExportError::Metrics { .. })
        ));
        assert!(EpochSizes::read(&dir.path().join("none.csv"))
            .unwrap()
            .is_none());
    }
}
