//! What a run is and what it leaves behind, for the launcher that writes it and for every
//! tool that reads a run (eval, inspect, sweep): the run config and the settings that change
//! it, the backends it names, the run directory and its files, the types of its MCAP
//! records, each role's report, the run's progress and summary, and their readers. Nothing
//! here starts a process or opens a transport, so a reader of runs builds without them.

pub mod backend;
pub mod checkpoint;
pub mod config;
pub mod files;
pub mod layout;
pub mod record;
pub mod reports;
pub mod run_dir;
pub mod settings;
pub mod summary;

pub use checkpoint::load_agent;
pub use config::RunConfig;
pub use files::{files_with_extension, named_arrangements, read_json, write_json};
pub use layout::ProcessLayout;
pub use reports::{
    ActorReport, BufferReport, Fault, HostReport, HostSummary, LearnerReport, ProcessEntry,
    SUCCESS_WINDOW, StreamCount,
};
pub use run_dir::RunDir;
pub use summary::{ActorProgress, Progress, Summary, percent};
