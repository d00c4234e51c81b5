//! The learning rule: the loss sees only the executed pixel, frozen nets stay put, labels
//! converge where Q* expects, checkpoints and weights round-trip, and training learns, on
//! steps as the buffer serves them (compressed and back) as on the raw ones.

use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use learner::checkpoint::config_hash;
use learner::{
    Checkpoint, LearningConfig, LrDecay, Manifest, NextState, Sample, SavedNets, TrainedNet,
    Trainer, executed_pixel_loss, outcome_loss,
};
use qnet::{Geometry, NetInput, QNetConfig, QNets, RotatedQMaps};
use sim::{Action, Camera, Primitive, ROTATIONS, SimConfig, Tabletop};

/// A net's parameters as bytes, to compare.
fn weights(net: &qnet::PrimitiveNet) -> Vec<u8> {
    net.clone().into_record().into_bytes().unwrap().to_vec()
}

fn trainer(trained: TrainedNet) -> Trainer {
    trainer_with(LearningConfig::default(), trained)
}

fn trainer_with(learning: LearningConfig, trained: TrainedNet) -> Trainer {
    trainer_from(
        QNets::new(&QNetConfig::default(), &Device::flex()),
        learning,
        trained,
    )
}

/// A trainer of given nets. Two trainers that must start alike share one `QNets`: the
/// backend's random generator is the whole process's, so tests running beside each other
/// draw from it in between any two inits.
fn trainer_from(nets: QNets, learning: LearningConfig, trained: TrainedNet) -> Trainer {
    let config = QNetConfig::default();
    Trainer::new(nets, &config, 112, &learning, trained, &Device::flex())
}

/// Samples from a real scene: grasps at each visible object's first pixel.
fn samples(primitive: Primitive, label: f32) -> Vec<Sample> {
    let (tabletop, _) = Tabletop::random(&SimConfig::with_pixel_size(0.004), 5, 21).unwrap();
    let maps = Camera::new(tabletop.grid()).render(&tabletop);
    maps.visible_ids()
        .into_iter()
        .take(4)
        .enumerate()
        .map(|(k, id)| {
            let i = maps.ids.iter().position(|&v| v == id).unwrap();
            Sample {
                input: NetInput::encode(&maps, id),
                action: Action {
                    primitive,
                    rotation: (3 * k) as u8,
                    row: i / 112,
                    col: i % 112,
                },
                label,
                weight: 1.0,
                succeeded: label > 0.0,
            }
        })
        .collect()
}

/// The gradient of `loss` on `values`.
fn gradient(values: &Tensor<1>, loss: Tensor<1>) -> Vec<f32> {
    let grads = loss.backward();
    values
        .grad(&grads)
        .unwrap()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap()
}

#[test]
fn the_loss_is_the_weighted_huber_loss_of_the_executed_pixels_q() {
    let device = Device::flex().autodiff();
    let q = Tensor::<1>::from_floats([0.3, 0.9], &device).require_grad();
    let loss = executed_pixel_loss(q.clone(), &[2.5, 0.2], &[1.0, 0.5], 1.0);
    // Past delta the Huber loss is linear (|q - y| - 1/2), within it quadratic.
    let want = (2.2 - 0.5) + 0.5 * 0.5 * 0.7 * 0.7;
    let got = loss.clone().into_data().try_to_vec::<f32>().unwrap()[0];
    assert!((got - want).abs() < 1e-5, "{got} vs {want}");
    let grad = gradient(&q, loss);
    assert!(
        (grad[0] + 1.0).abs() < 1e-5 && (grad[1] - 0.5 * 0.7).abs() < 1e-5,
        "{grad:?}"
    );
}

#[test]
fn the_outcome_loss_is_the_weighted_cross_entropy_of_the_executed_pixels_logit() {
    let device = Device::flex().autodiff();
    let values = [3.1f32, -1.7];
    let logits = Tensor::<1>::from_floats(values, &device).require_grad();
    let (succeeded, weights) = ([1.0, 0.0], [1.0, 0.5]);
    let loss = outcome_loss(logits.clone(), &succeeded, &weights);
    let sigmoid = |x: f32| 1.0 / (1.0 + (-f64::from(x)).exp());
    let want: f64 = (0..2)
        .map(|j| {
            let (p, y) = (sigmoid(values[j]), succeeded[j] as f64);
            -(y * p.ln() + (1.0 - y) * (1.0 - p).ln()) * weights[j] as f64
        })
        .sum();
    let got = loss.clone().into_data().try_to_vec::<f32>().unwrap()[0];
    assert!(
        (f64::from(got) - want).abs() < 1e-5 * want.max(1.0),
        "{got} vs {want}"
    );
    let grad = gradient(&logits, loss);
    // d/dx of the cross-entropy is sigmoid(x) - y, scaled by the sample's weight.
    for j in 0..2 {
        let want = (sigmoid(values[j]) - succeeded[j] as f64) * weights[j] as f64;
        assert!((f64::from(grad[j]) - want).abs() < 1e-5, "item {j}");
    }
}

#[test]
fn an_outcome_head_learns_which_grasps_took_the_goal() {
    let config = QNetConfig {
        grasp_outcome_head: true,
        ..QNetConfig::default()
    };
    let learning = LearningConfig {
        learning_rate: 1e-3,
        ..LearningConfig::default()
    };
    let nets = QNets::new(&config, &Device::flex());
    assert!(nets.grasp.has_outcome() && !nets.push.has_outcome());
    let mut trainer = Trainer::new(
        nets,
        &config,
        112,
        &learning,
        TrainedNet::Grasp,
        &Device::flex(),
    );
    // Half the grasps took the goal; all share one Q label, so only the outcome tells them
    // apart.
    let batch: Vec<Sample> = samples(Primitive::Grasp, 1.0)
        .into_iter()
        .enumerate()
        .map(|(k, s)| Sample {
            succeeded: k % 2 == 0,
            ..s
        })
        .collect();
    let items: Vec<(&NetInput, u8)> = batch
        .iter()
        .map(|s| (&s.input, s.action.rotation))
        .collect();
    let geometry = Geometry::new(112, &config);
    // The init comes from the process's shared generator, so how fast the head separates
    // the grasps varies between runs: look every 40 steps, up to 240.
    let mut executed = Vec::new();
    for _ in 0..6 {
        for _ in 0..40 {
            trainer.train_step(&batch).unwrap();
        }
        let (_, logits) = trainer
            .published_nets()
            .q_and_outcome_maps(Primitive::Grasp, &items, &geometry)
            .unwrap();
        let logits = logits.expect("the grasp net's outcome maps");
        let logits = logits.into_data().try_to_vec::<f32>().unwrap();
        executed = batch
            .iter()
            .enumerate()
            .map(|(j, s)| logits[(j * 112 + s.action.row) * 112 + s.action.col])
            .collect();
        if batch
            .iter()
            .zip(&executed)
            .all(|(s, &logit)| (logit > 0.0) == s.succeeded)
        {
            break;
        }
    }
    for (j, (s, logit)) in batch.iter().zip(&executed).enumerate() {
        assert_eq!(*logit > 0.0, s.succeeded, "grasp {j}: logits {executed:?}");
    }
}

#[test]
fn a_frozen_net_does_not_change_and_refuses_samples() {
    let mut trainer = trainer(TrainedNet::Grasp);
    let push_before = weights(&trainer.published_nets().push);
    let grasp_before = weights(&trainer.published_nets().grasp);
    for _ in 0..3 {
        trainer.train_step(&samples(Primitive::Grasp, 1.0)).unwrap();
    }
    let push_after = weights(&trainer.published_nets().push);
    let grasp_after = weights(&trainer.published_nets().grasp);
    assert_eq!(
        push_before, push_after,
        "the frozen push net is untouched, trunks included"
    );
    assert_ne!(grasp_before, grasp_after, "the trained grasp net learns");
    let error = trainer
        .train_step(&samples(Primitive::Push, 0.5))
        .unwrap_err();
    assert!(error.to_string().contains("frozen"), "{error}");

    trainer.set_trained(TrainedNet::Push);
    trainer.train_step(&samples(Primitive::Push, 0.5)).unwrap();
    let grasp_frozen = weights(&trainer.published_nets().grasp);
    assert_eq!(grasp_after, grasp_frozen);
}

/// Every float parameter (batch norm running statistics included), in visiting order.
fn parameters(nets: &QNets) -> Vec<f32> {
    struct Collect(Vec<f32>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let values = param.val().into_data().try_to_vec::<f32>().unwrap();
            self.0.extend(values);
        }
    }
    let mut collect = Collect(Vec::new());
    nets.visit(&mut collect);
    collect.0
}

fn averaging_config(polyak_rate: f32, publish_average: bool) -> LearningConfig {
    LearningConfig {
        polyak_rate,
        publish_average,
        ..LearningConfig::default()
    }
}

fn averaging(polyak_rate: f32, publish_average: bool) -> Trainer {
    trainer_with(
        averaging_config(polyak_rate, publish_average),
        TrainedNet::Grasp,
    )
}

fn assert_close(got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g - w).abs() <= 1e-5 * (1.0 + w.abs()),
            "value {i}: {g}, want {w}"
        );
    }
}

#[test]
fn the_polyak_average_is_a_plain_mean_until_one_over_the_rate_updates_then_moves_by_the_rate() {
    // The same start and batches: the averaging trainer's trained nets are the plain one's.
    let start = QNets::new(&QNetConfig::default(), &Device::flex());
    let mut plain = trainer_from(start.clone(), LearningConfig::default(), TrainedNet::Grasp);
    let mut averaged = trainer_from(start, averaging_config(0.5, true), TrainedNet::Grasp);
    let batch = samples(Primitive::Grasp, 1.5);
    let mut trained = Vec::new();
    for _ in 0..3 {
        plain.train_step(&batch).unwrap();
        averaged.train_step(&batch).unwrap();
        trained.push(parameters(&plain.published_nets()));
    }
    let moved = trained[0]
        .iter()
        .zip(&trained[1])
        .filter(|(a, b)| a != b)
        .count();
    assert!(moved > 1000, "updates move the grasp net ({moved} values)");

    // After updates 1 and 2 the mean of the trained nets (rate 1, then 1/2); after the
    // third, the rate itself: the average moves half way to the third nets.
    let mean: Vec<f32> = trained[0]
        .iter()
        .zip(&trained[1])
        .map(|(a, b)| (a + b) / 2.0)
        .collect();
    let want: Vec<f32> = mean
        .iter()
        .zip(&trained[2])
        .map(|(m, t)| m + 0.5 * (t - m))
        .collect();
    assert_close(&parameters(&averaged.published_nets()), &want);
}

#[test]
fn an_average_kept_for_checkpoints_alone_leaves_the_actors_the_trained_nets() {
    let mut trainer = averaging(0.5, false);
    let batch = samples(Primitive::Grasp, 1.5);
    trainer.train_step(&batch).unwrap();
    let first = parameters(&trainer.published_nets());
    trainer.train_step(&batch).unwrap();
    let second = parameters(&trainer.published_nets());
    assert_ne!(first, second, "actors get the newest trained nets");

    let (weights, trained) = trainer.checkpoint_weights().unwrap();
    let nets = |bytes: &[u8]| parameters(&trainer.published_nets().load_bytes(bytes).unwrap());
    let mean: Vec<f32> = first
        .iter()
        .zip(&second)
        .map(|(a, b)| (a + b) / 2.0)
        .collect();
    assert_close(&nets(&weights), &mean);
    assert!(nets(&trained.expect("the trained nets are kept")) == second);
}

#[test]
fn training_lowers_the_loss_on_a_fixed_replay_set() {
    let mut trainer = trainer(TrainedNet::Grasp);
    let batch = samples(Primitive::Grasp, 1.5);
    let first = trainer.train_step(&batch).unwrap().loss;
    let mut last = first;
    for _ in 0..60 {
        last = trainer.train_step(&batch).unwrap().loss;
    }
    assert!(last < 0.3 * first, "loss {first} -> {last}");
    assert_eq!(trainer.updates(), 61);
}

#[test]
fn steps_served_by_the_compressing_buffer_train_as_the_raw_steps_do() {
    use buffer::{BufferConfig, ReplayBuffer, Serving};
    use experience::Transition;
    use rand::SeedableRng;

    // One-step episodes of real scenes: a grasp that picks the goal.
    let raw: Vec<Transition> = (0..4u64)
        .map(|episode| {
            let config = SimConfig::with_pixel_size(0.004);
            let (tabletop, _) = Tabletop::random(&config, 3 + episode as usize, episode).unwrap();
            let obs = Camera::new(tabletop.grid()).render(&tabletop);
            let goal = obs.visible_ids()[0];
            let i = obs.ids.iter().position(|&v| v == goal).unwrap();
            Transition {
                episode,
                step: 0,
                goal,
                action: Action {
                    primitive: Primitive::Grasp,
                    rotation: 2,
                    row: i / 112,
                    col: i % 112,
                },
                obs,
                reward: 1.0,
                grasped: Some(goal),
                next_value: None,
                next: None,
            }
        })
        .collect();
    let serving = Serving {
        push_reward: policy::PushReward::Change,
        sampled: vec![Primitive::Grasp],
        successors: false,
    };
    let config = BufferConfig {
        min_size_to_sample: 1,
        ..BufferConfig::default()
    };
    let mut buffer = ReplayBuffer::new(config, serving).unwrap();
    for t in &raw {
        buffer.add_step(t.clone(), Some(1.0)).unwrap();
        buffer.end_episode(t.episode, t.grasped).unwrap();
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let served = buffer
        .sample(Primitive::Grasp, 8, &mut rng)
        .unwrap()
        .unpack()
        .unwrap();
    let sample = |t: &Transition, weight: f32| Sample {
        input: NetInput::encode(&t.obs, t.goal),
        action: t.action,
        label: 1.5,
        weight,
        succeeded: t.goal_grasped(),
    };
    let batch: Vec<Sample> = served
        .iter()
        .map(|item| {
            let original = &raw[item.transition.episode as usize];
            let from_buffer = sample(&item.transition, item.weight);
            assert_eq!(
                from_buffer.input,
                sample(original, item.weight).input,
                "the nets see what the actor saw, bit for bit"
            );
            from_buffer
        })
        .collect();
    let mut trainer = trainer(TrainedNet::Grasp);
    let first = trainer.train_step(&batch).unwrap().loss;
    let mut last = first;
    for _ in 0..40 {
        last = trainer.train_step(&batch).unwrap().loss;
    }
    assert!(last < 0.3 * first, "loss {first} -> {last}");
}

#[test]
fn a_grasp_and_its_mirror_image_teach_as_two_grasps() {
    // With `mirror_grasps` a grasp teaches what it and its mirror image (the observation
    // mirrored, the pixel's column and the jaw angle mirrored) teach as two samples without:
    // the same items, so from the same nets the same loss, step after step.
    let nets = QNets::new(&QNetConfig::default(), &Device::flex());
    let learning = |mirror_grasps| LearningConfig {
        learning_rate: 1e-3,
        mirror_grasps,
        ..LearningConfig::default()
    };
    let mut taught = trainer_from(nets.clone(), learning(true), TrainedNet::Grasp);
    let mut both = trainer_from(nets, learning(false), TrainedNet::Grasp);
    let samples = samples(Primitive::Grasp, 1.5);
    let mirror_images = samples.iter().map(|s| Sample {
        input: s.input.mirrored(),
        action: Action {
            rotation: (ROTATIONS - s.action.rotation) % ROTATIONS,
            col: s.input.side - 1 - s.action.col,
            ..s.action
        },
        ..s.clone()
    });
    let with_mirror_images: Vec<Sample> = samples.iter().cloned().chain(mirror_images).collect();
    for step in 0..3 {
        let a = taught.train_step(&samples).unwrap().loss;
        let b = both.train_step(&with_mirror_images).unwrap().loss;
        assert!(
            (a - b).abs() <= 1e-4 * b.abs(),
            "step {step}: loss {a} taught with mirror images, {b} on them as samples"
        );
    }
}

#[test]
fn a_sample_and_its_translated_copy_teach_as_two_samples() {
    // With `translate_samples` a sample teaches what it and a copy moved by some shift of
    // at most that many pixels (the observation and the pixel moved alike) teach as two
    // samples without: so one of those shifts gives the same loss from the same nets.
    let reach = 2;
    for (primitive, trained) in [
        (Primitive::Grasp, TrainedNet::Grasp),
        (Primitive::Push, TrainedNet::Push),
    ] {
        let nets = QNets::new(&QNetConfig::default(), &Device::flex());
        let learning = |translate_samples| LearningConfig {
            learning_rate: 1e-3,
            translate_samples,
            ..LearningConfig::default()
        };
        let sample = samples(primitive, 1.5).swap_remove(0);
        let taught = trainer_from(nets.clone(), learning(reach), trained)
            .train_step(std::slice::from_ref(&sample))
            .unwrap()
            .loss;
        let reach = reach as isize;
        let shifts =
            (-reach..=reach).flat_map(|rows| (-reach..=reach).map(move |cols| (rows, cols)));
        let matching: Vec<(isize, isize)> = shifts
            .filter(|&shift| shift != (0, 0))
            .filter(|&(rows, cols)| {
                let moved = Sample {
                    input: sample.input.translated(rows, cols),
                    action: Action {
                        row: sample.action.row.wrapping_add_signed(rows),
                        col: sample.action.col.wrapping_add_signed(cols),
                        ..sample.action
                    },
                    ..sample.clone()
                };
                let both = trainer_from(nets.clone(), learning(0), trained)
                    .train_step(&[sample.clone(), moved])
                    .unwrap()
                    .loss;
                (taught - both).abs() <= 1e-5 * both.abs()
            })
            .collect();
        assert_eq!(
            matching.len(),
            1,
            "{primitive:?}: loss {taught} taught with a translated copy; shifts giving it as two samples: {matching:?}"
        );
    }
}

#[test]
fn spot_q_teaches_a_grasps_peak_outside_its_goal_a_zero_beside_it() {
    // With `spot_q` a grasp sample whose Q map (at its rotation, under the nets as published)
    // peaks outside its goal mask teaches what it and a failed grasp at that peak teach as
    // two samples; one whose goal is hidden, and a push, teach as without it.
    let nets = QNets::new(&QNetConfig::default(), &Device::flex());
    let learning = |spot_q| LearningConfig {
        learning_rate: 1e-3,
        spot_q,
        ..LearningConfig::default()
    };
    let loss = |spot_q, trained, batch: &[Sample]| {
        trainer_from(nets.clone(), learning(spot_q), trained)
            .train_step(batch)
            .unwrap()
            .loss
    };
    let close = |a: f32, b: f32| (a - b).abs() <= 1e-5 * b.abs().max(1e-3);
    let geometry = trainer_from(nets.clone(), learning(false), TrainedNet::Grasp)
        .geometry()
        .clone();
    let mut peaks_outside = 0;
    for sample in samples(Primitive::Grasp, 1.5) {
        let map = trainer_from(nets.clone(), learning(false), TrainedNet::Grasp)
            .published_nets()
            .q_maps(
                Primitive::Grasp,
                &[(&sample.input, sample.action.rotation)],
                &geometry,
            )
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let (_, _, row, col) = policy::QMaps::new(1, 112, map)
            .unwrap()
            .best_where(&[true; 112 * 112])
            .unwrap();
        let peak = row * 112 + col;
        let taught = loss(true, TrainedNet::Grasp, std::slice::from_ref(&sample));
        if sample.input.mask[peak] > 0.0 {
            let plain = loss(false, TrainedNet::Grasp, std::slice::from_ref(&sample));
            assert!(
                close(taught, plain),
                "peak on the goal: {taught} vs {plain}"
            );
            continue;
        }
        peaks_outside += 1;
        let failed = Sample {
            action: Action {
                row: peak / 112,
                col: peak % 112,
                ..sample.action
            },
            label: 0.0,
            succeeded: false,
            ..sample.clone()
        };
        let both = loss(false, TrainedNet::Grasp, &[sample.clone(), failed]);
        assert!(
            close(taught, both),
            "spot_q's loss {taught}; the sample and a failed grasp at the peak: {both}"
        );
        let hidden = Sample {
            input: NetInput {
                mask: vec![0.0; sample.input.mask.len()],
                ..sample.input.clone()
            },
            ..sample.clone()
        };
        let taught = loss(true, TrainedNet::Grasp, std::slice::from_ref(&hidden));
        let plain = loss(false, TrainedNet::Grasp, std::slice::from_ref(&hidden));
        assert!(close(taught, plain), "hidden goal: {taught} vs {plain}");
    }
    assert!(peaks_outside > 0, "no sample's map peaks off its goal");
    let pushes = samples(Primitive::Push, -0.5);
    let taught = loss(true, TrainedNet::Push, &pushes);
    let plain = loss(false, TrainedNet::Push, &pushes);
    assert!(close(taught, plain), "pushes: {taught} vs {plain}");
}

#[test]
fn checkpoints_round_trip_to_identical_q_maps() {
    let config = QNetConfig::default();
    let mut trained = trainer(TrainedNet::Grasp);
    trained.train_step(&samples(Primitive::Grasp, 1.0)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let checkpoint = Checkpoint::at(dir.path().join("ckpt"));
    let (weights, trained_nets) = trained.checkpoint_weights().unwrap();
    assert_eq!(
        trained_nets, None,
        "without an average the weights are the trained nets"
    );
    let saved = SavedNets {
        manifest: Manifest {
            stage: 1,
            updates: trained.updates(),
            side: 112,
            config_hash: config_hash(&config),
        },
        weights,
        trained: None,
    };
    checkpoint.save(&saved).unwrap();

    let read = checkpoint.load(&config_hash(&config)).unwrap();
    assert_eq!(read, saved);
    let mut resumed = trainer(TrainedNet::Grasp);
    resumed.resume(&read).unwrap();
    assert_eq!(resumed.updates(), trained.updates());
    let input = &samples(Primitive::Grasp, 1.0)[0].input;
    let q = |t: &Trainer| {
        t.published_nets()
            .all_rotations(Primitive::Grasp, input, t.geometry())
            .unwrap()
    };
    assert_eq!(q(&resumed), q(&trained));

    let other = QNetConfig {
        trunk_widths: vec![8, 8],
        ..QNetConfig::default()
    };
    let error = checkpoint.load(&config_hash(&other)).unwrap_err();
    assert!(
        error.to_string().contains("manifest.toml") && error.to_string().contains("config_hash"),
        "{error}"
    );
}

#[test]
fn a_resumed_average_goes_on_from_both_nets_and_the_update_count() {
    let mut first = averaging(0.1, false);
    let batch = samples(Primitive::Grasp, 1.5);
    for _ in 0..3 {
        first.train_step(&batch).unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let checkpoint = Checkpoint::at(dir.path().join("ckpt"));
    let (weights, trained) = first.checkpoint_weights().unwrap();
    let saved = SavedNets {
        manifest: Manifest {
            stage: 1,
            updates: first.updates(),
            side: 112,
            config_hash: config_hash(&QNetConfig::default()),
        },
        weights,
        trained,
    };
    checkpoint.save(&saved).unwrap();
    assert!(dir.path().join("ckpt/trained.bpk").exists());

    let mut resumed = averaging(0.1, false);
    resumed
        .resume(&checkpoint.load(&saved.manifest.config_hash).unwrap())
        .unwrap();
    assert_eq!(resumed.updates(), 3);
    // Both nets come back: the average for checkpoints, the trained nets for the actors.
    let nets =
        |t: &Trainer, bytes: &[u8]| parameters(&t.published_nets().load_bytes(bytes).unwrap());
    let (average, trained) = resumed.checkpoint_weights().unwrap();
    assert!(nets(&resumed, &average) == nets(&first, &saved.weights));
    assert!(nets(&resumed, &trained.unwrap()) == nets(&first, saved.trained.as_ref().unwrap()));
    assert!(parameters(&resumed.published_nets()) == parameters(&first.published_nets()));
    assert!(nets(&first, &saved.weights) != parameters(&first.published_nets()));

    // A checkpoint written later without an average drops the stale trained nets.
    checkpoint
        .save(&SavedNets {
            trained: None,
            ..saved
        })
        .unwrap();
    assert!(!dir.path().join("ckpt/trained.bpk").exists());
}

#[test]
fn the_learners_next_values_are_chosen_by_the_trained_nets_and_valued_by_the_target_nets() {
    let nets = QNets::new(&QNetConfig::default(), &Device::flex());
    let learning = |every: u64| LearningConfig {
        learning_rate: 1e-2,
        target_update_every: every,
        ..LearningConfig::default()
    };
    let mut trainer = trainer_from(nets.clone(), learning(3), TrainedNet::Push);
    let first = samples(Primitive::Push, 1.0);
    // Where pushes may start: the left half of the table.
    let allowed: Vec<bool> = (0..112 * 112).map(|i| i % 112 < 56).collect();
    let state = NextState {
        input: first[0].input.clone(),
        primitive: Primitive::Push,
        allowed: allowed.clone(),
    };
    let geometry = trainer.geometry().clone();
    let best = |nets: &QNets| {
        nets.all_rotations(Primitive::Push, &state.input, &geometry)
            .unwrap()
            .best_where(&allowed)
            .unwrap()
    };
    let value = |trainer: &Trainer| trainer.next_values(std::slice::from_ref(&state)).unwrap();

    // Two updates: the target nets are still the first nets.
    for _ in 0..2 {
        trainer.train_step(&first).unwrap();
    }
    let (trained_q, rotation, row, col) = best(&trainer.published_nets());
    let first_nets = nets.valid();
    let target_q = first_nets
        .all_rotations(Primitive::Push, &state.input, &geometry)
        .unwrap()
        .get(rotation, row, col);
    let got = value(&trainer).expect("the config values next states")[0];
    assert!(
        (got - target_q).abs() < 1e-5,
        "{got} vs the target's {target_q}"
    );
    assert!(
        (got - trained_q).abs() > 1e-3,
        "the trained nets' own value {trained_q} is not the target's {got}"
    );

    // The third update refreshes the target nets: both roles are the trained nets now.
    trainer.train_step(&first).unwrap();
    let (trained_q, ..) = best(&trainer.published_nets());
    let got = value(&trainer).unwrap()[0];
    assert!((got - trained_q).abs() < 1e-5, "{got} vs {trained_q}");

    // Several states of both primitives at once (each primitive's scored in one batch):
    // each state's value as alone, in its own place.
    let states: Vec<NextState> = first
        .iter()
        .zip([
            Primitive::Grasp,
            Primitive::Push,
            Primitive::Grasp,
            Primitive::Push,
        ])
        .map(|(sample, primitive)| NextState {
            input: sample.input.clone(),
            primitive,
            allowed: allowed.clone(),
        })
        .collect();
    let together = trainer.next_values(&states).unwrap().unwrap();
    let alone: Vec<f32> = states
        .iter()
        .map(|state| {
            trainer
                .next_values(std::slice::from_ref(state))
                .unwrap()
                .unwrap()[0]
        })
        .collect();
    assert_eq!(together.len(), 4);
    for (a, b) in together.iter().zip(&alone) {
        assert!(
            (a - b).abs() < 1e-5,
            "together {together:?}, alone {alone:?}"
        );
    }
    assert_ne!(together[0], together[1]);

    // Without target nets the learner values nothing: labels keep their actors' values.
    let plain = trainer_from(nets, learning(0), TrainedNet::Push);
    assert_eq!(value(&plain), None);
}

#[test]
fn a_decaying_step_size_falls_geometrically_to_its_end_and_stays() {
    let learning = LearningConfig {
        learning_rate: 1e-3,
        lr_decay: Some(LrDecay {
            to: 1e-5,
            over_updates: 100,
        }),
        ..LearningConfig::default()
    };
    let mut trainer = trainer_with(learning, TrainedNet::Grasp);
    assert_eq!(trainer.learning_rate(), 1e-3);
    let resume_at = |trainer: &mut Trainer, updates: u64| {
        let (weights, trained) = trainer.checkpoint_weights().unwrap();
        let manifest = Manifest {
            stage: 1,
            updates,
            side: 112,
            config_hash: String::new(),
        };
        trainer
            .resume(&SavedNets {
                manifest,
                weights,
                trained,
            })
            .unwrap();
        trainer.learning_rate()
    };
    let halfway = resume_at(&mut trainer, 50);
    assert!((halfway - 1e-4).abs() < 1e-9, "{halfway}");
    for after in [100, 400] {
        let lr = resume_at(&mut trainer, after);
        assert!((lr - 1e-5).abs() < 1e-12, "{after} updates: {lr}");
    }
    trainer.train_step(&samples(Primitive::Grasp, 1.0)).unwrap();
    assert_eq!(trainer.updates(), 401);
}

#[test]
fn a_net_without_context_convolutions_fusion_or_outcome_head_keeps_its_first_config_hash() {
    // The net config as it was before `context_dilations` existed.
    #[derive(serde::Serialize)]
    struct Before {
        trunk_widths: Vec<usize>,
        head_width: usize,
    }
    let before = Before {
        trunk_widths: vec![8, 16],
        head_width: 64,
    };
    let plain = QNetConfig {
        trunk_widths: vec![8, 16],
        context_dilations: Vec::new(),
        fuse_context: false,
        head_width: 64,
        grasp_outcome_head: false,
        rotation_equivariant: false,
    };
    assert_eq!(config_hash(&plain), config_hash(&before));
    let with_outcome = QNetConfig {
        grasp_outcome_head: true,
        ..plain.clone()
    };
    assert_ne!(config_hash(&with_outcome), config_hash(&before));
    let wide = QNetConfig {
        context_dilations: vec![1, 2],
        ..plain
    };
    assert_ne!(config_hash(&wide), config_hash(&before));
    let fused = QNetConfig {
        fuse_context: true,
        ..wide.clone()
    };
    assert_ne!(config_hash(&fused), config_hash(&wide));
    let equivariant = QNetConfig {
        rotation_equivariant: true,
        ..wide.clone()
    };
    assert_ne!(config_hash(&equivariant), config_hash(&wide));
}
