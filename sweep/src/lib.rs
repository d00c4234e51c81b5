//! Training sweeps over a base training config: the sweep file ([`Sweep::load`]), its
//! expansion into runs with resolved configs ([`Sweep::expand`]), the Slurm job-array script
//! ([`job_array_script`]), Slurm's accounting output ([`parse_sacct`], [`parse_squeue`]) and
//! the grouping of runs over seeds ([`group_by_all_but`]).
//!
//! [`runner`] is `pushgrasp sweep`: it runs them, each as a `pushgrasp train` of its own, in
//! a bounded local pool or as a Slurm job array, and reports where they stand and what they
//! gave. Everything outside it is pure.

mod accounting;
mod axis;
mod error;
mod expand;
mod file;
mod group;
mod keys;
mod options;
pub mod runner;
mod slurm;

pub use accounting::{JobState, parse_sacct, parse_squeue};
pub use axis::Axis;
pub use error::SweepError;
pub use expand::{RunPlan, dry_run_listing};
pub use file::{Budget, Sweep};
pub use group::group_by_all_but;
pub use options::SlurmOptions;
pub use slurm::{bash_quote, job_array_script};
