//! `pushgrasp train`: the distributed runtime. A launcher starts the buffer, the learner and
//! N actors, as child processes of this binary talking over iceoryx2 shared memory (the
//! default) or as threads talking over crossbeam channels (`--threads`); the roles' code is
//! the same in both wirings. With `--listen`, actors on other hosts join the run
//! (`pushgrasp join`, [`join()`]): each host keeps its own shared memory, and one bridge per
//! host carries what must cross (the `bridge` crate).

pub mod actor;
pub mod buffer;
pub mod hosts;
pub mod join;
pub mod launch;
pub mod learner;
pub mod lifeline;
pub mod machine;
pub mod memory;
pub mod pipeline;
pub mod pretrain;
pub mod process_log;
pub mod progress;
pub mod role;
pub mod signals;
pub mod stopwatch;
pub mod supervisor;
pub mod worker;

pub use join::{JoinArgs, join};
pub use launch::{TrainArgs, train};
pub use lifeline::{Lifeline, STATUS_EVERY, stop_requested};
pub use pretrain::{PretrainArgs, pretrain};
pub use role::{RoleArgs, RoleId, role_process};
