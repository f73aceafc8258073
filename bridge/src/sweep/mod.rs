//! Scaling sweeps over trainer services: the grid of trainings ([`grid`]), the pure dispatch
//! ledger ([`ledger`]) and the driver that spreads the points over every trainer that answers and
//! collects their results ([`run`]).

pub mod grid;
pub mod ledger;
pub mod run;

pub use grid::{data_budget, Regularisers, SweepGrid, SweepPoint};
pub use ledger::{Ledger, PointState};
pub use run::{
    read_results, run_dir, run_sweep, write_csv, PointResult, SweepData, SweepEvent, SweepOptions,
    SweepSummary, CSV_HEADER,
};
