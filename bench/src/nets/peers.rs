//! The peers of `bench learner`: onnxruntime's inference and PyTorch's training step of the
//! same nets, run by Python beside ours, and how to install them where they did not run.

use std::path::PathBuf;

use learner::LearningConfig;
use qnet::Inference;
use serde_json::{Map, Value};
use sim::Primitive;

use super::side::{SideFigures, SideNets, Training, samples};
use crate::peer;

/// What the peers gave over all sides, or why they did not run.
pub(super) struct Peers {
    python: PathBuf,
    reps: usize,
    figures: Map<String, Value>,
    missing: Option<String>,
    torch_version: Option<Value>,
    torch_device: Option<Value>,
    torch_missing: Option<String>,
}

impl Peers {
    /// Peers run by `python`, timing `reps` repetitions.
    pub(super) fn new(python: PathBuf, reps: usize) -> Self {
        Peers {
            python,
            reps,
            figures: Map::new(),
            missing: None,
            torch_version: None,
            torch_device: None,
            torch_missing: None,
        }
    }

    /// onnxruntime's inference of the side's nets beside ours (`infer`, the low-resolution
    /// maps from `inference`).
    pub(super) fn onnxruntime(
        &mut self,
        s: &SideNets,
        inference: &Inference,
        rotated: [&[f32]; 3],
        infer: f64,
        put: &mut SideFigures,
    ) {
        let ours = [Primitive::Push, Primitive::Grasp]
            .map(|primitive| inference.low_maps(primitive, rotated, &s.geometry));
        let run = peer::PeerRun {
            nets: &s.nets,
            rotated,
            n: s.passes,
            padded: s.geometry.padded(),
            ours: [&ours[0], &ours[1]],
            reps: self.reps,
            threads: rayon::current_num_threads(),
        };
        match peer::onnxruntime_figures(&self.python, &run) {
            Ok(peer) => {
                let ort = peer["ort_infer_ms"].as_f64().unwrap_or(f64::NAN);
                put.put("ort_infer_16rot_ms", ort);
                put.put("infer_vs_ort", infer / ort);
                put.put(
                    "ort_max_rel_diff",
                    peer["ort_max_rel_diff"].as_f64().unwrap_or(f64::NAN),
                );
                self.figures.extend(peer);
            }
            Err(why) => self.missing = Some(format!("{why:#}")),
        }
    }

    /// PyTorch's training step of the same net beside ours, on the CPU.
    pub(super) fn torch(
        &mut self,
        s: &SideNets,
        rotated: [&[f32]; 3],
        training: &Training,
        gflop_batch_train: f64,
        device: &str,
        put: &mut SideFigures,
    ) {
        let (learning, batch) = (LearningConfig::default(), samples(s, 8));
        let run = peer::TrainingPeerRun {
            net: &training.before_batch.grasp,
            rotated,
            geometry: &s.geometry,
            samples: &batch,
            learning: &learning,
            ours: &training.first_batch,
            reps: self.reps,
            threads: rayon::current_num_threads(),
            device,
        };
        match peer::torch_figures(&self.python, &run) {
            Ok(peer) => {
                let figure = |key: &str| peer[key].as_f64().unwrap_or(f64::NAN);
                let torch_batch = figure("torch_batch_train_step_ms");
                put.put("torch_train_step_ms", figure("torch_train_step_ms"));
                put.put("torch_batch_train_step_ms", torch_batch);
                put.put("batch_train_vs_torch", training.batch_train / torch_batch);
                put.put(
                    "torch_achieved_gflops",
                    gflop_batch_train / (torch_batch / 1e3),
                );
                put.put("torch_max_rel_diff", figure("torch_max_rel_diff"));
                self.torch_version = peer.get("torch_version").cloned();
                self.torch_device = peer.get("torch_device").cloned();
            }
            Err(why) => self.torch_missing = Some(format!("{why:#}")),
        }
    }

    /// The peers' own figures (their versions, numpy's sgemm peak), or why they did not run
    /// and how to install them.
    pub(super) fn report(self, no_peer: bool, figures: &mut Map<String, Value>) {
        let mut peer_figures = self.figures;
        match self.missing {
            None if no_peer => {
                figures.insert("onnxruntime".into(), "not run (--no-peer)".into());
            }
            None => {
                for key in ["sgemm_peak_gflops", "ort_version", "numpy_version"] {
                    if let Some(value) = peer_figures.remove(key) {
                        figures.insert(key.into(), value);
                    }
                }
            }
            Some(why) => {
                eprintln!(
                    "onnxruntime was not run ({why}); to run it beside ours:\n  \
                     python3 -m venv target/bench-venv && \
                     target/bench-venv/bin/python3 -m pip install onnxruntime onnx numpy"
                );
                figures.insert("onnxruntime".into(), format!("not run: {why}").into());
            }
        }
        if let Some(version) = self.torch_version {
            figures.insert("torch_version".into(), version);
        }
        if let Some(device) = self.torch_device {
            figures.insert("torch_device".into(), device);
        }
        if let Some(why) = self.torch_missing {
            eprintln!(
                "PyTorch's training step was not run ({why}); to run it beside ours (about 5 GB \
                 with its CUDA libraries):\n  target/bench-venv/bin/python3 -m pip install torch"
            );
            figures.insert("torch".into(), format!("not run: {why}").into());
        }
    }
}
