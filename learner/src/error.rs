use std::path::PathBuf;

use thiserror::Error;

#[derive(Debug, Error)]
pub enum LearnerError {
    #[error(transparent)]
    QNet(#[from] qnet::QNetError),
    #[error(transparent)]
    Sim(#[from] sim::SimError),
    #[error("a {0:?} sample reached the trainer while that net is frozen")]
    Frozen(sim::Primitive),
    #[error("the trained {0:?} net's Q maps are NaN wherever the next state allows it to act")]
    NoQValue(sim::Primitive),
    #[error("{path}: {message}")]
    Checkpoint { path: PathBuf, message: String },
}
