//! What `bench learner` times at one heightmap side: the nets on a scene's input, the figures
//! named with the side, and the timed training steps and publications.

use anyhow::Result;
use learner::{Sample, StepReport, Trainer};
use qnet::{ActingNets, Geometry, NetInput, QNets};
use serde_json::{Map, Value};
use sim::{Action, Primitive};

use crate::thread_cpu::ThreadCpu;
use crate::{median, ms, timed};

/// The nets timed at one heightmap side, on the input of a settled 10-object scene.
pub(super) struct SideNets {
    pub(super) side: usize,
    pub(super) input: NetInput,
    pub(super) nets: QNets,
    pub(super) geometry: Geometry,
    pub(super) acting: ActingNets,
    /// The passes over rotated inputs that the 16 rotations take.
    pub(super) passes: usize,
}

/// The figures of one side, each named with the side.
pub(super) struct SideFigures<'a> {
    pub(super) figures: &'a mut Map<String, Value>,
    pub(super) suffix: String,
}

impl SideFigures<'_> {
    pub(super) fn put(&mut self, name: &str, value: f64) {
        self.put_value(name, value.into());
    }

    pub(super) fn put_value(&mut self, name: &str, value: Value) {
        self.figures.insert(format!("{name}{}", self.suffix), value);
    }
}

/// The training steps timed on a side's grasp net.
pub(super) struct Training {
    pub(super) train: f64,
    pub(super) batch_train: f64,
    pub(super) publish: f64,
    /// The published nets before the first batch step, and that step's report.
    pub(super) before_batch: QNets,
    pub(super) first_batch: StepReport,
    /// The host threads' CPU time after and before the batch steps, where it can be read.
    pub(super) threads: Option<(ThreadCpu, ThreadCpu)>,
}

/// The median time of `reps` runs of both nets, push then grasp.
pub(super) fn both_ms(reps: usize, run: &dyn Fn(Primitive)) -> f64 {
    median(
        (0..reps)
            .map(|_| ms(timed(|| [Primitive::Push, Primitive::Grasp].map(run)).1))
            .collect(),
    )
}

/// Each pass's input rotated beforehand (colour, depth, mask): what the peers run.
pub(super) fn rotated_planes(s: &SideNets) -> [Vec<f32>; 3] {
    let [mut colour, mut depth, mut mask] = [Vec::new(), Vec::new(), Vec::new()];
    for k in 0..s.passes as u8 {
        s.geometry
            .rotate_input(&s.input, k, [&mut colour, &mut depth, &mut mask]);
    }
    [colour, depth, mask]
}

/// `batch` successful grasps near the middle of the side's input, at rotations in turn.
pub(super) fn samples(s: &SideNets, batch: usize) -> Vec<Sample> {
    let sample = |k: usize| Sample {
        input: s.input.clone(),
        action: Action {
            primitive: Primitive::Grasp,
            rotation: (k % 16) as u8,
            row: s.side / 2,
            col: s.side / 2 + k,
        },
        label: 1.0,
        weight: 1.0,
        succeeded: true,
    };
    (0..batch).map(sample).collect()
}

/// The median time of `reps` training steps on `samples`, and the report of the untimed
/// step before them.
pub(super) fn train_step_ms(
    trainer: &mut Trainer,
    samples: &[Sample],
    reps: usize,
) -> Result<(f64, StepReport)> {
    let first = trainer.train_step(samples)?;
    let times = (0..reps)
        .map(|_| timed(|| trainer.train_step(samples)).1)
        .map(ms)
        .collect();
    Ok((median(times), first))
}

/// The median time of `reps` publications of the trainer's nets as bytes: what the learner
/// sends the actors after every update at `publish_every = 1`. An untimed one first: on a
/// GPU it waits for the work still queued (the last step's backward pass), which is the
/// step's, not the publication's.
pub(super) fn publish_ms(trainer: &Trainer, reps: usize) -> Result<f64> {
    trainer.published_nets().to_bytes()?;
    let times = (0..reps)
        .map(|_| {
            let (bytes, time) = timed(|| trainer.published_nets().to_bytes());
            bytes.map(|_| ms(time))
        })
        .collect::<Result<_, _>>()?;
    Ok(median(times))
}
