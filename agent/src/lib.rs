//! The agent: the push and grasp Q-networks acting through the hierarchical policy
//! ([`Agent`]), the same code for training actors and for evaluation, and the evaluation
//! itself ([`evaluate()`]): test runs on the paper's arrangements or on random scenes, scored
//! with the paper's completion, goal grasp success and motion number, and optionally under
//! the authors' own test protocol ([`test_learning`]).

mod agent;
pub mod evaluate;
pub mod failures;
pub mod metrics;
pub mod test_learning;

pub use agent::{Agent, AgentError, Choice, Situation};
pub use evaluate::{EvalConfig, Scene, evaluate};
pub use failures::FailureReport;
pub use metrics::{ActionAt, ActionRecord, CaseMetrics, RunOutcome, RunRecord};
pub use test_learning::TestLearning;
