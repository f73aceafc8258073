//! Scaling sweeps over trainer services: the grid of trainings ([`grid`]) and its data budgets
//! ([`budget`]), the pure dispatch
//! ledger ([`ledger`]) and the driver that spreads the points over every trainer that answers and
//! collects their results ([`run`]).

pub mod budget;
pub mod grid;
pub mod ledger;
pub mod run;

pub use budget::{
    budget_windows, data_budget, data_budget_for, record_budgets, BudgetCell, DataShape,
    PAPER_BUDGET,
};
pub use grid::{Regularisers, SweepGrid, SweepPoint};
pub use ledger::{Ledger, PointState};
pub use run::{
    read_results, run_dir, run_sweep, write_csv, PointResult, SweepData, SweepEvent, SweepOptions,
    SweepSummary, CSV_HEADER,
};
