//! Rollout traces as CSV: one row per step (the reset's row first), written by `cabc-sim rollout --trace` and read
//! back, as the driven line, by `cabc-sim track --trace`.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use anyhow::{Context, Result};

use crate::env::{EnvObservation, Truncation};
use crate::vehicle::Input;

/// The columns of a trace.
pub const HEADER: &str =
    "step,t,a,delta,v_long,v_tran,omega,s,x_tran,e_psi,X,Y,psi,reward,lap_no,truncation";

/// One row of a trace: the step, its time and action, the observation after it.
#[derive(Clone, Copy, Debug)]
pub struct Row<'a> {
    pub step: u64,
    /// Simulated time (s).
    pub t: f64,
    pub action: Input,
    pub obs: &'a EnvObservation,
    pub reward: f64,
    pub lap_no: u32,
    pub truncation: Option<Truncation>,
}

/// A trace file being written.
pub struct TraceWriter {
    out: BufWriter<File>,
}

impl TraceWriter {
    /// Creates `path` and writes the header.
    pub fn create(path: &Path) -> Result<TraceWriter> {
        let file = File::create(path)
            .with_context(|| format!("creating trace file {}", path.display()))?;
        let mut out = BufWriter::new(file);
        writeln!(out, "{HEADER}")?;
        Ok(TraceWriter { out })
    }

    pub fn row(&mut self, r: &Row) -> Result<()> {
        let w = &mut self.out;
        write!(w, "{},{:.1},{},{}", r.step, r.t, r.action[0], r.action[1])?;
        for v in r.obs.state.iter().chain(r.obs.pose.iter()) {
            write!(w, ",{v}")?;
        }
        let truncation = r.truncation.map(|t| t.to_string()).unwrap_or_default();
        writeln!(w, ",{},{},{truncation}", r.reward, r.lap_no)?;
        Ok(())
    }

    pub fn finish(mut self) -> Result<()> {
        self.out.flush().context("writing the trace")
    }
}

/// The (X, Y) points of a CSV trace with columns named `X` and `Y` (a rollout's, or an MPCC drive's).
pub fn read_xy(path: &Path) -> Result<Vec<(f64, f64)>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading trace {}", path.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines
        .next()
        .context("empty trace file")?
        .split(',')
        .map(str::trim)
        .collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .with_context(|| format!("trace has no {name} column"))
    };
    let (ix, iy) = (col("X")?, col("Y")?);
    let mut pts = Vec::new();
    for (n, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let f: Vec<&str> = line.split(',').collect();
        let get = |i: usize| -> Result<f64> {
            f.get(i)
                .context("short row")?
                .trim()
                .parse::<f64>()
                .with_context(|| format!("trace line {}: bad number", n + 2))
        };
        pts.push((get(ix)?, get(iy)?));
    }
    Ok(pts)
}
