//! The outcome of a QP solve: Clarabel's statuses plus the ones this crate adds.

use clarabel::solver::SolverStatus;
use serde::{Deserialize, Serialize};

/// Solver outcome of one QP, or of a whole control step (the first failing QP, else the last one).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum QpStatus {
    /// No QP was solved.
    NotRun,
    /// The assembled data contained NaN or ±∞ (diverged linearisation); the QP was not handed to the solver.
    NonFiniteData,
    /// Clarabel could not be set up with this data.
    SetupFailed,
    /// Clarabel's statuses.
    Solved,
    AlmostSolved,
    PrimalInfeasible,
    DualInfeasible,
    AlmostPrimalInfeasible,
    AlmostDualInfeasible,
    MaxIterations,
    MaxTime,
    NumericalError,
    InsufficientProgress,
    CallbackTerminated,
    Unsolved,
}

impl QpStatus {
    /// The status name (Clarabel's spelling for Clarabel's statuses).
    pub fn name(self) -> &'static str {
        match self {
            Self::NotRun => "NotRun",
            Self::NonFiniteData => "NonFiniteData",
            Self::SetupFailed => "SetupFailed",
            Self::Solved => "Solved",
            Self::AlmostSolved => "AlmostSolved",
            Self::PrimalInfeasible => "PrimalInfeasible",
            Self::DualInfeasible => "DualInfeasible",
            Self::AlmostPrimalInfeasible => "AlmostPrimalInfeasible",
            Self::AlmostDualInfeasible => "AlmostDualInfeasible",
            Self::MaxIterations => "MaxIterations",
            Self::MaxTime => "MaxTime",
            Self::NumericalError => "NumericalError",
            Self::InsufficientProgress => "InsufficientProgress",
            Self::CallbackTerminated => "CallbackTerminated",
            Self::Unsolved => "Unsolved",
        }
    }

    /// Whether the solution may be used (expert.md §7: HPIPM status 0; `AlmostSolved` only if configured).
    pub fn is_success(self, accept_almost_solved: bool) -> bool {
        self == Self::Solved || (accept_almost_solved && self == Self::AlmostSolved)
    }
}

impl From<SolverStatus> for QpStatus {
    fn from(s: SolverStatus) -> Self {
        match s {
            SolverStatus::Unsolved => Self::Unsolved,
            SolverStatus::Solved => Self::Solved,
            SolverStatus::PrimalInfeasible => Self::PrimalInfeasible,
            SolverStatus::DualInfeasible => Self::DualInfeasible,
            SolverStatus::AlmostSolved => Self::AlmostSolved,
            SolverStatus::AlmostPrimalInfeasible => Self::AlmostPrimalInfeasible,
            SolverStatus::AlmostDualInfeasible => Self::AlmostDualInfeasible,
            SolverStatus::MaxIterations => Self::MaxIterations,
            SolverStatus::MaxTime => Self::MaxTime,
            SolverStatus::NumericalError => Self::NumericalError,
            SolverStatus::InsufficientProgress => Self::InsufficientProgress,
            SolverStatus::CallbackTerminated => Self::CallbackTerminated,
        }
    }
}

impl std::fmt::Display for QpStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
