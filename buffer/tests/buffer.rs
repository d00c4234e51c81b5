//! The buffer's behaviour through its public API: sampling statistics, importance weights,
//! annealing, stale updates, separate storage, relabelling, the rate limit and snapshots.

use std::path::PathBuf;

use buffer::{
    AssembleError, BufferConfig, EpisodeAssembler, PrioritizedReplay, ReplayBuffer, ReplayError,
    Serving, SnapshotErrorKind,
};
use experience::observation::store;
use experience::{BatchItem, Key, StoredTransition, Transition};
use policy::PushReward;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sim::{Action, Heightmaps, ObjectId, PixelGrid, Primitive};

fn maps() -> Heightmaps {
    Heightmaps::new(PixelGrid::new(0.004).unwrap())
}

fn step(episode: u64, step: u32, primitive: Primitive, goal: ObjectId) -> Transition {
    Transition {
        episode,
        step,
        goal,
        obs: maps(),
        action: Action {
            primitive,
            rotation: 3,
            row: 10,
            col: 20,
        },
        reward: 0.0,
        grasped: None,
        next_value: Some(0.5),
        next: None,
    }
}

/// A stored transition with its observation decompressed.
fn unpacked(t: &StoredTransition) -> Transition {
    t.clone().try_map_obs(|obs| obs.unpack()).unwrap()
}

fn config(capacity: usize) -> BufferConfig {
    BufferConfig {
        capacity: buffer::Capacity::Steps(capacity),
        ..BufferConfig::default()
    }
}

#[test]
fn sampling_frequencies_are_proportional_to_priority_to_the_alpha() {
    let mut replay = PrioritizedReplay::new(&config(8)).unwrap();
    let priorities = [0.1, 0.5, 1.0, 2.0, 3.0, 4.0, 0.0, 8.0];
    let keys: Vec<Key> = priorities
        .iter()
        .enumerate()
        .map(|(i, p)| {
            replay
                .insert(store(step(i as u64, 0, Primitive::Grasp, 1)), Some(*p))
                .unwrap()
        })
        .collect();
    let alpha = 0.6;
    let eps = BufferConfig::default().priority_epsilon;
    let weights: Vec<f64> = priorities
        .iter()
        .map(|p| f64::max(*p, eps).powf(alpha))
        .collect();
    let total: f64 = weights.iter().sum();

    let mut counts = [0u64; 8];
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let (batches, n) = (4_000, 32);
    for _ in 0..batches {
        let batch = replay.sample(Primitive::Grasp, n, &mut rng).unwrap();
        for (item, probability) in batch.items.iter().zip(&batch.probabilities) {
            counts[item.key.slot as usize] += 1;
            let expected = weights[item.key.slot as usize] / total;
            assert!((probability - expected).abs() < 1e-12);
        }
    }
    let draws = (batches * n) as f64;
    // The slot of priority 0 is floored at epsilon: rare, but not starved of probability.
    assert!(replay.priority(&keys[6]).unwrap() == eps);
    let chi2: f64 = counts
        .iter()
        .zip(&weights)
        .map(|(&c, w)| {
            let e = draws * w / total;
            (c as f64 - e).powi(2) / e
        })
        .sum();
    // 7 degrees of freedom: P(chi2 > 30) is about 1e-4.
    assert!(chi2 < 30.0, "chi2 {chi2}, counts {counts:?}");
    // And the uniform hypothesis must be rejected, or the test proves nothing.
    let uniform: f64 = counts
        .iter()
        .map(|&c| (c as f64 - draws / 8.0).powi(2) / (draws / 8.0))
        .sum();
    assert!(uniform > 1000.0);
}

#[test]
fn importance_weights_follow_the_formula_on_a_hand_case() {
    let cfg = BufferConfig {
        alpha: 1.0,
        beta_start: 0.5,
        beta_anneal_samples: 1_000_000,
        ..config(4)
    };
    let mut replay = PrioritizedReplay::new(&cfg).unwrap();
    let a = replay
        .insert(store(step(0, 0, Primitive::Push, 1)), Some(1.0))
        .unwrap();
    let b = replay
        .insert(store(step(1, 0, Primitive::Push, 1)), Some(3.0))
        .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    // 64 strata over a total of 4: slot a owns the first 16, so both appear.
    let batch = replay.sample(Primitive::Push, 64, &mut rng).unwrap();
    assert_eq!(batch.beta, 0.5);
    // P = 1/4 and 3/4, N = 2: w = (2 P)^-0.5 = sqrt(2) and sqrt(2/3); the largest is a's.
    let expected_b = ((2.0f64 * 0.75).powf(-0.5) / (2.0f64 * 0.25).powf(-0.5)) as f32;
    let (mut seen_a, mut seen_b) = (0, 0);
    for (item, &probability) in batch.items.iter().zip(&batch.probabilities) {
        if item.key == a {
            seen_a += 1;
            assert_eq!(probability, 0.25);
            assert_eq!(item.weight, 1.0);
        } else {
            assert_eq!(item.key, b);
            seen_b += 1;
            assert_eq!(probability, 0.75);
            assert!((item.weight - expected_b).abs() < 1e-6, "{}", item.weight);
        }
    }
    assert_eq!((seen_a, seen_b), (16, 48));
}

/// A replay of `positives` grasps rewarded 1 and `others` rewarded 0, all at priority 1, in
/// that order.
fn rewarded_grasps(config: &BufferConfig, positives: u64, others: u64) -> PrioritizedReplay {
    let mut replay = PrioritizedReplay::new(config).unwrap();
    for episode in 0..positives + others {
        let mut grasp = step(episode, 0, Primitive::Grasp, 1);
        grasp.reward = if episode < positives { 1.0 } else { 0.0 };
        replay.insert(store(grasp), Some(1.0)).unwrap();
    }
    replay
}

/// The share of positive rewards among `batches` batches of `n`.
fn positive_share_drawn(replay: &mut PrioritizedReplay, batches: usize, n: usize) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut positives = 0;
    for _ in 0..batches {
        let batch = replay.sample(Primitive::Grasp, n, &mut rng).unwrap();
        positives += batch
            .items
            .iter()
            .filter(|i| i.transition.reward > 0.0)
            .count();
    }
    positives as f64 / (batches * n) as f64
}

#[test]
fn a_positive_share_draws_that_share_from_positive_rewards_and_weighs_it_back() {
    let cfg = BufferConfig {
        beta_start: 1.0,
        ..config(100)
    };
    // 10 positives of 100 at equal priority: a tenth of the draws, or half with the share.
    let mut plain = rewarded_grasps(&cfg, 10, 90);
    let drawn = positive_share_drawn(&mut plain, 2_000, 4);
    assert!((drawn - 0.1).abs() < 0.01, "{drawn}");
    let balanced = BufferConfig {
        positive_share: Some(0.5),
        ..cfg
    };
    let mut replay = rewarded_grasps(&balanced, 10, 90);
    let drawn = positive_share_drawn(&mut replay, 2_000, 4);
    assert!((drawn - 0.5).abs() < 0.01, "{drawn}");
    // An odd batch rounds at random, the share kept in expectation.
    let drawn = positive_share_drawn(&mut replay, 4_000, 3);
    assert!((drawn - 0.5).abs() < 0.01, "{drawn}");

    // P(i) = half the batch times the item's share of its kind. The weights undo priority
    // alone, not the share, which is meant to change what is learned from: at equal
    // priorities every weight is 1, a positive drawn nine times as often as an other.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let batch = replay.sample(Primitive::Grasp, 4, &mut rng).unwrap();
    let mut kinds = [0, 0];
    for (item, &probability) in batch.items.iter().zip(&batch.probabilities) {
        let positive = item.transition.reward > 0.0;
        let expected = if positive { 0.5 / 10.0 } else { 0.5 / 90.0 };
        assert!((probability - expected).abs() < 1e-12, "{probability}");
        assert_eq!(item.weight, 1.0);
        kinds[usize::from(positive)] += 1;
    }
    assert_eq!(kinds, [2, 2]);
    // A priority raised within a kind is weighed back as without a share: 9 others at 1
    // and one at 8 (p^alpha 8^0.6), 10 positives at 1; N = 20, beta 1.
    let key = batch
        .items
        .iter()
        .find(|i| i.transition.reward == 0.0)
        .unwrap()
        .key;
    replay.update_priority(&key, 8.0).unwrap();
    let raised = 8.0f64.powf(0.6);
    let total = 19.0 + raised;
    let batch = replay.sample(Primitive::Grasp, 64, &mut rng).unwrap();
    let weight = |p: f64| (100.0 * p / total).powf(-1.0);
    let largest = weight(1.0);
    for item in &batch.items {
        let p = if item.key == key { raised } else { 1.0 };
        let expected = (weight(p) / largest) as f32;
        assert!(
            (item.weight - expected).abs() < 1e-6,
            "{} {expected}",
            item.weight
        );
    }
    assert!(batch.items.iter().any(|i| i.key == key));
}

#[test]
fn at_a_positive_share_a_kind_with_nothing_left_gives_the_whole_batch_to_the_other() {
    let balanced = BufferConfig {
        positive_share: Some(0.5),
        ..config(2)
    };
    // Only positives, then only others: no draw is owed to the missing kind.
    let mut replay = rewarded_grasps(&balanced, 2, 0);
    assert_eq!(positive_share_drawn(&mut replay, 100, 4), 1.0);
    let mut replay = rewarded_grasps(&balanced, 0, 2);
    assert_eq!(positive_share_drawn(&mut replay, 100, 4), 0.0);
    // A positive overwritten by others leaves its kind's tree: it is never drawn again.
    let mut replay = rewarded_grasps(&balanced, 1, 2);
    assert_eq!(replay.len(Primitive::Grasp), 2);
    assert_eq!(positive_share_drawn(&mut replay, 100, 4), 0.0);
    // And an other overwritten by a positive is drawn as one.
    let mut grasp = step(9, 0, Primitive::Grasp, 1);
    grasp.reward = 1.0;
    replay.insert(store(grasp), Some(1.0)).unwrap();
    let drawn = positive_share_drawn(&mut replay, 1_000, 4);
    assert!((drawn - 0.5).abs() < 0.03, "{drawn}");
}

#[test]
fn beta_anneals_linearly_to_one_over_sampled_items() {
    let cfg = BufferConfig {
        beta_start: 0.4,
        beta_anneal_samples: 100,
        ..config(4)
    };
    let mut replay = PrioritizedReplay::new(&cfg).unwrap();
    replay
        .insert(store(step(0, 0, Primitive::Grasp, 1)), None)
        .unwrap();
    replay
        .insert(store(step(1, 0, Primitive::Push, 1)), None)
        .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    assert_eq!(replay.beta(), 0.4);
    let batch = replay.sample(Primitive::Grasp, 50, &mut rng).unwrap();
    assert_eq!(batch.beta, 0.4, "a batch uses the beta before it");
    assert!((replay.beta() - 0.7).abs() < 1e-12);
    // Both primitives advance the same clock.
    replay.sample(Primitive::Push, 50, &mut rng).unwrap();
    assert_eq!(replay.beta(), 1.0);
    replay.sample(Primitive::Push, 50, &mut rng).unwrap();
    assert_eq!(replay.beta(), 1.0);
    assert_eq!(replay.sampled(), 150);
}

#[test]
fn an_update_for_an_overwritten_slot_is_ignored() {
    let mut replay = PrioritizedReplay::new(&config(2)).unwrap();
    let old = replay
        .insert(store(step(0, 0, Primitive::Grasp, 1)), Some(1.0))
        .unwrap();
    let kept = replay
        .insert(store(step(1, 0, Primitive::Grasp, 1)), Some(1.0))
        .unwrap();
    let new = replay
        .insert(store(step(2, 0, Primitive::Grasp, 1)), Some(2.0))
        .unwrap();
    assert_eq!(old.slot, new.slot, "the third insert reuses the first slot");
    assert_ne!(old.generation, new.generation);
    assert_eq!(replay.get(&old), None);
    assert_eq!(replay.get(&new).unwrap().episode, 2);

    assert!(!replay.update_priority(&old, 100.0).unwrap());
    assert_eq!(replay.priority(&new), Some(2.0));
    assert_eq!(replay.stale_updates(), 1);
    assert!(replay.update_priority(&kept, 5.0).unwrap());
    assert_eq!(replay.priority(&kept), Some(5.0));
    // A key of the other primitive's ring, or past the capacity, names nothing.
    let wrong = Key {
        primitive: Primitive::Push,
        ..kept
    };
    assert!(!replay.update_priority(&wrong, 1.0).unwrap());
    let outside = Key { slot: 9, ..kept };
    assert!(!replay.update_priority(&outside, 1.0).unwrap());
    assert!(matches!(
        replay.update_priority(&kept, f64::NAN),
        Err(ReplayError::BadPriority(p)) if p.is_nan()
    ));
}

#[test]
fn new_items_without_a_priority_get_the_largest_so_far() {
    let mut replay = PrioritizedReplay::new(&config(4)).unwrap();
    let first = replay
        .insert(store(step(0, 0, Primitive::Push, 1)), None)
        .unwrap();
    assert_eq!(
        replay.priority(&first),
        Some(1.0),
        "the maximum starts at 1"
    );
    let big = replay
        .insert(store(step(1, 0, Primitive::Push, 1)), Some(4.0))
        .unwrap();
    replay.update_priority(&big, 0.0).unwrap();
    let next = replay
        .insert(store(step(2, 0, Primitive::Push, 1)), None)
        .unwrap();
    assert_eq!(replay.priority(&next), Some(4.0));
    assert_eq!(
        replay.priority(&big),
        Some(BufferConfig::default().priority_epsilon)
    );
}

#[test]
fn push_and_grasp_storage_are_separate() {
    let mut replay = PrioritizedReplay::new(&config(3)).unwrap();
    let grasp = replay
        .insert(store(step(0, 0, Primitive::Grasp, 1)), Some(1.0))
        .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    assert_eq!(
        replay.sample(Primitive::Push, 4, &mut rng).unwrap_err(),
        ReplayError::Empty(Primitive::Push)
    );
    // Ten pushes overrun the push ring but never the grasp one.
    for i in 0..10 {
        replay
            .insert(store(step(i + 1, 0, Primitive::Push, 1)), Some(1.0))
            .unwrap();
    }
    assert_eq!(replay.len(Primitive::Push), 3);
    assert_eq!(replay.len(Primitive::Grasp), 1);
    assert_eq!(replay.inserted(Primitive::Push), 10);
    assert_eq!(replay.get(&grasp).unwrap().episode, 0);
    let pushes = replay.sample(Primitive::Push, 64, &mut rng).unwrap();
    assert!(
        pushes
            .items
            .iter()
            .all(|i| i.transition.primitive() == Primitive::Push
                && i.key.primitive == Primitive::Push
                && i.transition.episode >= 8)
    );
    let grasps = replay.sample(Primitive::Grasp, 8, &mut rng).unwrap();
    assert!(grasps.items.iter().all(|i| i.key == grasp));
}

/// Object 9 at rows/cols 50..60 (height 5 cm), boxed in by object 3 out to 45..65 when
/// `boxed`; object 9 is absent when `present` is false.
fn scene(present: bool, boxed: bool) -> Heightmaps {
    let mut m = maps();
    let side = m.side();
    for r in 45..65 {
        for c in 45..65 {
            let inner = (50..60).contains(&r) && (50..60).contains(&c);
            let i = r * side + c;
            if inner && present {
                m.ids[i] = 9;
                m.height[i] = 0.05;
            } else if !inner && boxed {
                m.ids[i] = 3;
                m.height[i] = 0.05;
            }
        }
    }
    m
}

/// The paper's relabelling, with its dense push reward.
const DENSE: Option<PushReward> = Some(PushReward::Dense);

/// A run with the dense push reward whose learner samples both primitives and values
/// pushes' next states itself.
fn serving_both() -> Serving {
    Serving {
        push_reward: PushReward::Dense,
        sampled: vec![Primitive::Push, Primitive::Grasp],
        successors: true,
    }
}

/// An episode for goal 5: a push seeing no object 9, a push that clears around 9, a push
/// that changes nothing, and a grasp that picks 9.
fn non_goal_episode(episode: u64) -> Vec<Transition> {
    let mut steps = vec![
        step(episode, 0, Primitive::Push, 5),
        step(episode, 1, Primitive::Push, 5),
        step(episode, 2, Primitive::Push, 5),
        step(episode, 3, Primitive::Grasp, 5),
    ];
    steps[0].obs = scene(false, true);
    steps[1].obs = scene(true, true);
    steps[2].obs = scene(true, false);
    steps[3].obs = scene(true, false);
    for (t, r) in steps.iter_mut().zip([-0.5, 0.0, -0.5, 0.0]) {
        t.reward = r;
    }
    steps[3].grasped = Some(9);
    steps[3].next_value = Some(1.25);
    steps
}

#[test]
fn a_grasp_of_another_object_is_relabelled_with_its_pushes() {
    let mut assembler = EpisodeAssembler::new();
    let originals = non_goal_episode(4);
    // Arrival order does not matter: steps are assembled by index.
    for (i, t) in originals.iter().enumerate().rev() {
        assembler.add(t.clone(), Some(i as f64)).unwrap();
    }
    let ready = assembler.end(4, Some(9), DENSE).unwrap();
    assert_eq!(ready.len(), 4 + 3);
    for (i, r) in ready[..4].iter().enumerate() {
        let Transition { next, .. } = unpacked(&r.transition);
        let alone = Transition {
            next: None,
            ..unpacked(&r.transition)
        };
        assert_eq!(
            alone, originals[i],
            "originals are stored unchanged but for their successor"
        );
        // Each push carries the next step, shared; the grasp that ends the episode, none.
        match originals.get(i + 1).filter(|_| i < 3) {
            Some(following) => {
                let next = next.expect("a push carries its next step");
                assert_eq!(
                    (&next.obs, next.primitive),
                    (&following.obs, following.primitive())
                );
                let packed = &r.transition.next.as_ref().unwrap().obs;
                assert!(packed.shares(&ready[i + 1].transition.obs));
            }
            None => assert_eq!(next, None),
        }
        assert_eq!(r.priority, Some(i as f64));
        assert!(!r.relabelled);
    }
    let copies: Vec<_> = ready[4..].iter().collect();
    assert!(copies.iter().all(|r| r.relabelled && r.priority.is_none()));
    assert!(copies.iter().all(|r| r.transition.goal == 9));
    // Push 0 did not see object 9 and has no copy; push 1 cleared around it; push 2 did not.
    let steps: Vec<u32> = copies.iter().map(|r| r.transition.step).collect();
    assert_eq!(steps, [1, 2, 3]);
    assert_eq!(copies[0].transition.reward, 0.5);
    assert_eq!(copies[1].transition.reward, -0.5);
    // Apart from goal and reward, a copy is its original, masks coming from the stored ids.
    let expected_push = Transition {
        goal: 9,
        reward: 0.5,
        ..unpacked(&ready[1].transition)
    };
    assert_eq!(unpacked(&copies[0].transition), expected_push);
    assert_eq!(
        copies[1].transition.next.as_ref().unwrap().primitive,
        Primitive::Grasp,
        "the last copied push is followed by the grasp of its goal"
    );
    // A copy shares its original's packed observation: no bytes are stored twice.
    assert!(copies[0].transition.obs.shares(&ready[1].transition.obs));
    assert!(copies[2].transition.obs.shares(&ready[3].transition.obs));
    assert_eq!(
        unpacked(&copies[0].transition)
            .goal_mask()
            .iter()
            .filter(|m| **m)
            .count(),
        100
    );
    let grasp = &copies[2].transition;
    assert_eq!((grasp.reward, grasp.grasped), (1.0, Some(9)));
    assert!(
        grasp.goal_grasped(),
        "the copy picked its goal, so its label bootstraps"
    );
    assert_eq!(grasp.next_value, Some(1.25));
    let original = &originals[3];
    assert_eq!(
        (original.reward, original.goal_grasped()),
        (0.0, false),
        "the original earned nothing"
    );
    assert_eq!(assembler.relabelled(), 3);
    assert_eq!(assembler.open_episodes(), 0);
}

#[test]
fn relabelled_pushes_earn_the_runs_push_reward_and_nothing_is_copied_without_relabelling() {
    let rewards = |relabelling: Option<PushReward>| {
        let mut assembler = EpisodeAssembler::new();
        for t in non_goal_episode(4) {
            assembler.add(t, None).unwrap();
        }
        let ready = assembler.end(4, Some(9), relabelling).unwrap();
        let copies: Vec<f32> = ready
            .iter()
            .filter(|r| r.relabelled)
            .map(|r| r.transition.reward)
            .collect();
        (ready.len(), copies, assembler.relabelled())
    };
    // Push 1 cleared around object 9, push 2 did not; the grasp copy earns 1.
    assert_eq!(rewards(DENSE), (7, vec![0.5, -0.5, 1.0], 3));
    assert_eq!(
        rewards(Some(PushReward::Change)),
        (7, vec![0.5, 0.0, 1.0], 3)
    );
    assert_eq!(rewards(Some(PushReward::None)), (7, vec![0.0, 0.0, 1.0], 3));
    assert_eq!(rewards(None), (4, vec![], 0));

    // Through the buffer: `relabel = false` stores the originals only.
    let mut buffer = ReplayBuffer::new(
        BufferConfig {
            relabel: false,
            ..config(16)
        },
        serving_both(),
    )
    .unwrap();
    for t in non_goal_episode(1) {
        buffer.add_step(t, Some(0.5)).unwrap();
    }
    assert_eq!(buffer.end_episode(1, Some(9)).unwrap().len(), 4);
    assert_eq!(buffer.stats().relabelled, 0);
}

#[test]
fn a_grasp_of_the_goal_or_of_nothing_creates_no_copies() {
    let mut assembler = EpisodeAssembler::new();
    let mut goal_episode = non_goal_episode(1);
    for t in &mut goal_episode {
        t.goal = 9;
    }
    goal_episode[3].reward = 1.0;
    for t in &goal_episode {
        assembler.add(t.clone(), None).unwrap();
    }
    let ready = assembler.end(1, Some(9), DENSE).unwrap();
    assert_eq!(ready.len(), 4);
    assert!(ready.iter().all(|r| !r.relabelled));

    let mut failed = non_goal_episode(2);
    failed[3].grasped = None;
    for t in &failed {
        assembler.add(t.clone(), None).unwrap();
    }
    assert_eq!(assembler.end(2, None, DENSE).unwrap().len(), 4);
    assert_eq!(assembler.relabelled(), 0);
}

#[test]
fn inconsistent_episodes_are_refused_and_stay_open() {
    let mut assembler = EpisodeAssembler::new();
    let steps = non_goal_episode(7);
    assembler.add(steps[0].clone(), None).unwrap();
    assert_eq!(
        assembler.add(steps[0].clone(), None),
        Err(AssembleError::DuplicateStep {
            episode: 7,
            step: 0
        })
    );
    assert!(matches!(
        assembler.add(steps[1].clone(), Some(f64::INFINITY)),
        Err(AssembleError::BadPriority { step: 1, .. })
    ));
    assembler.add(steps[2].clone(), None).unwrap();
    assembler.add(steps[3].clone(), None).unwrap();
    assert_eq!(
        assembler.end(7, Some(9), DENSE),
        Err(AssembleError::MissingStep {
            episode: 7,
            missing: 1
        })
    );
    assembler.add(steps[1].clone(), None).unwrap();
    assert_eq!(
        assembler.end(7, Some(4), DENSE),
        Err(AssembleError::GraspNotFound {
            episode: 7,
            object: 4
        })
    );
    assert_eq!(
        assembler.end(8, None, DENSE),
        Err(AssembleError::UnknownEpisode(8))
    );
    // Nothing was lost: a flush returns all four steps, in order.
    let flushed = assembler.flush(7);
    let order: Vec<u32> = flushed.iter().map(|r| r.transition.step).collect();
    assert_eq!(order, [0, 1, 2, 3]);
}

#[test]
fn the_buffer_stores_relabelled_episodes_and_limits_sampling() {
    let cfg = BufferConfig {
        min_size_to_sample: 6,
        samples_per_insert: 1.0,
        error_buffer: 2.0,
        ..config(16)
    };
    let mut buffer = ReplayBuffer::new(cfg, serving_both()).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for t in non_goal_episode(1) {
        buffer.add_step(t, Some(0.5)).unwrap();
    }
    assert_eq!(buffer.stats().open_episodes, 1);
    assert!(matches!(
        buffer.sample(Primitive::Grasp, 1, &mut rng),
        Err(ReplayError::RateLimited {
            inserts: 0,
            samples: 0
        })
    ));
    let keys = buffer.end_episode(1, Some(9)).unwrap();
    assert_eq!(keys.len(), 7);
    let stats = buffer.stats();
    assert_eq!((stats.push_len, stats.grasp_len), (5, 2));
    assert_eq!((stats.inserted, stats.relabelled), (7, 3));
    // 7 inserts, spi 1, min 6, buffer 2: diff 7, min_diff 4: 3 samples and no more.
    assert!(buffer.can_sample(3) && !buffer.can_sample(4));
    let batch = buffer.sample(Primitive::Grasp, 3, &mut rng).unwrap();
    let updates: Vec<(Key, f64)> = batch.items.iter().map(|i| (i.key, 2.0)).collect();
    assert!(matches!(
        buffer.sample(Primitive::Push, 1, &mut rng),
        Err(ReplayError::RateLimited {
            inserts: 7,
            samples: 3
        })
    ));
    assert_eq!(buffer.update_priorities(&updates).unwrap(), 3);
    assert_eq!(buffer.replay().priority(&updates[0].0), Some(2.0));
}

#[test]
fn only_inserts_of_sampled_primitives_count_toward_the_rate_limit() {
    let cfg = BufferConfig {
        min_size_to_sample: 1,
        samples_per_insert: 1.0,
        error_buffer: 2.0,
        ..config(16)
    };
    // Stage 2: the learner samples pushes only. Episodes of grasps alone must not hold the
    // actors back, however many arrive.
    let mut pushes_only = ReplayBuffer::new(
        cfg.clone(),
        Serving {
            push_reward: PushReward::Dense,
            sampled: vec![Primitive::Push],
            successors: false,
        },
    )
    .unwrap();
    let mut both = ReplayBuffer::new(cfg, serving_both()).unwrap();
    for episode in 0..6 {
        let mut grasp = step(episode, 0, Primitive::Grasp, 5);
        grasp.grasped = Some(5);
        for buffer in [&mut pushes_only, &mut both] {
            buffer.add_step(grasp.clone(), None).unwrap();
            buffer.end_episode(episode, Some(5)).unwrap();
        }
    }
    assert_eq!(pushes_only.stats().grasp_len, 6);
    assert_eq!(pushes_only.limiter().inserts(), 0);
    assert!(pushes_only.can_insert(1));
    assert!(!pushes_only.can_sample(1), "no push yet to sample");
    assert_eq!(both.limiter().inserts(), 6);
    assert!(
        !both.can_insert(1),
        "6 inserts, no samples: the limit holds"
    );
}

/// A buffer with stored items of both kinds, updated priorities, samples, and an open episode.
fn busy_buffer() -> ReplayBuffer {
    busy_buffer_drawing(None)
}

/// [`busy_buffer`] at a positive share (`[buffer] positive_share`).
fn busy_buffer_drawing(positive_share: Option<f64>) -> ReplayBuffer {
    let mut buffer = ReplayBuffer::new(
        BufferConfig {
            min_size_to_sample: 2,
            positive_share,
            ..config(5)
        },
        serving_both(),
    )
    .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for episode in 0..3 {
        for t in non_goal_episode(episode) {
            buffer.add_step(t, Some(0.25 * episode as f64)).unwrap();
        }
        buffer.end_episode(episode, Some(9)).unwrap();
    }
    reprioritise_sampled(&mut buffer, 4, 3.0, &mut rng);
    buffer
        .add_step(non_goal_episode(3).remove(0), None)
        .unwrap();
    buffer
}

/// Samples `n` pushes and gives each the priority `priority`, as the learner does.
fn reprioritise_sampled(buffer: &mut ReplayBuffer, n: usize, priority: f64, rng: &mut ChaCha8Rng) {
    let updates: Vec<(Key, f64)> = buffer
        .sample(Primitive::Push, n, rng)
        .unwrap()
        .items
        .iter()
        .map(|i| (i.key, priority))
        .collect();
    buffer.update_priorities(&updates).unwrap();
}

#[test]
fn a_snapshot_round_trips_exactly() {
    // At a positive share the sum trees rebuilt when read are one per kind of reward.
    for positive_share in [None, Some(0.5)] {
        let buffer = busy_buffer_drawing(positive_share);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("round-trip.snap");
        buffer.save(&path).unwrap();
        assert!(!PathBuf::from(format!("{}.tmp", path.display())).exists());
        let mut restored = ReplayBuffer::load(&path).unwrap();
        assert_eq!(restored, buffer, "{positive_share:?}");
        // And it behaves the same: the same draws from the same seed.
        let mut original = buffer;
        for primitive in [Primitive::Grasp, Primitive::Push] {
            let (mut r1, mut r2) = (ChaCha8Rng::seed_from_u64(4), ChaCha8Rng::seed_from_u64(4));
            let a = original.sample(primitive, 4, &mut r1).unwrap();
            let b = restored.sample(primitive, 4, &mut r2).unwrap();
            assert_eq!(a, b, "{positive_share:?}");
        }
        std::fs::remove_file(&path).unwrap();
    }
}

#[test]
fn a_copy_to_save_writes_the_buffer_as_it_was_when_copied() {
    let mut buffer = busy_buffer();
    let dir = tempfile::tempdir().unwrap();
    let (then, copied) = (dir.path().join("then.snap"), dir.path().join("copy.snap"));
    buffer.save(&then).unwrap();
    let copy = buffer.copy_to_save();
    // The buffer goes on while the copy waits to be written: new steps overwrite and add
    // slots, and sampled items get new priorities.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for episode in 10..14 {
        for t in non_goal_episode(episode) {
            buffer.add_step(t, Some(0.5)).unwrap();
        }
        buffer.end_episode(episode, Some(9)).unwrap();
    }
    reprioritise_sampled(&mut buffer, 8, 7.0, &mut rng);
    copy.save(&copied).unwrap();
    assert_eq!(
        std::fs::read(&copied).unwrap(),
        std::fs::read(&then).unwrap()
    );
    assert_ne!(ReplayBuffer::load(&copied).unwrap(), buffer);
}

#[test]
fn a_truncated_or_corrupted_snapshot_is_refused_naming_the_file() {
    let buffer = busy_buffer();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("damaged.snap");
    buffer.save(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();

    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let err = ReplayBuffer::load(&path).unwrap_err();
    assert!(
        matches!(err.kind, SnapshotErrorKind::Truncated { .. }),
        "{err}"
    );
    assert!(err.to_string().contains("damaged.snap"), "{err}");

    std::fs::write(&path, &bytes[..10]).unwrap();
    let err = ReplayBuffer::load(&path).unwrap_err();
    assert!(
        matches!(err.kind, SnapshotErrorKind::Truncated { .. }),
        "{err}"
    );

    let mut flipped = bytes.clone();
    let middle = flipped.len() / 2;
    flipped[middle] ^= 0x40;
    std::fs::write(&path, &flipped).unwrap();
    let err = ReplayBuffer::load(&path).unwrap_err();
    assert!(matches!(err.kind, SnapshotErrorKind::Checksum), "{err}");

    std::fs::write(&path, b"not a snapshot at all, just some text").unwrap();
    let err = ReplayBuffer::load(&path).unwrap_err();
    assert!(matches!(err.kind, SnapshotErrorKind::BadMagic), "{err}");

    std::fs::remove_file(&path).unwrap();
    let err = ReplayBuffer::load(&path).unwrap_err();
    assert!(matches!(err.kind, SnapshotErrorKind::Io(_)), "{err}");
    assert!(err.to_string().contains("damaged.snap"), "{err}");
}

/// A buffer holding one relabelled episode, and the keys of its originals and copies.
fn relabelled_buffer() -> (ReplayBuffer, Vec<Key>) {
    let mut buffer = ReplayBuffer::new(config(16), serving_both()).unwrap();
    for t in non_goal_episode(0) {
        buffer.add_step(t, None).unwrap();
    }
    let keys = buffer.end_episode(0, Some(9)).unwrap();
    (buffer, keys)
}

#[test]
fn pushes_are_stored_without_their_next_step_for_a_learner_that_does_not_value_it() {
    let serving = Serving {
        successors: false,
        ..serving_both()
    };
    let mut buffer = ReplayBuffer::new(config(16), serving).unwrap();
    for t in non_goal_episode(0) {
        buffer.add_step(t, None).unwrap();
    }
    let keys = buffer.end_episode(0, Some(9)).unwrap();
    assert_eq!(keys.len(), 7);
    for key in &keys {
        assert_eq!(buffer.replay().get(key).unwrap().next, None);
    }
    let (with, keys) = relabelled_buffer();
    assert!(with.replay().get(&keys[0]).unwrap().next.is_some());
}

#[test]
fn relabelled_copies_share_their_observation_through_a_snapshot() {
    let (buffer, keys) = relabelled_buffer();
    // Steps 0..4, then the copies of steps 1, 2 and 3.
    assert_eq!(keys.len(), 7);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("shared.snap");
    buffer.save(&path).unwrap();
    let restored = ReplayBuffer::load(&path).unwrap();
    assert_eq!(restored, buffer);
    let obs = |key: &Key| &restored.replay().get(key).unwrap().obs;
    for (copy, original) in [(4, 1), (5, 2), (6, 3)] {
        assert!(obs(&keys[copy]).shares(obs(&keys[original])));
        assert_eq!(
            unpacked(restored.replay().get(&keys[copy]).unwrap()).obs,
            non_goal_episode(0)[original].obs,
            "bit for bit after compression and a snapshot"
        );
    }
    assert!(!obs(&keys[1]).shares(obs(&keys[2])));
    // A push's successor in its own ring stays shared; one in the other ring is kept whole.
    let next = |key: &Key| {
        &restored
            .replay()
            .get(key)
            .unwrap()
            .next
            .as_ref()
            .unwrap()
            .obs
    };
    assert!(next(&keys[1]).shares(obs(&keys[2])));
    assert!(next(&keys[4]).shares(obs(&keys[2])));
    assert_eq!(next(&keys[2]), obs(&keys[3]));
}

#[test]
fn a_damaged_observation_in_a_snapshot_is_named() {
    let (buffer, keys) = relabelled_buffer();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("record.snap");
    buffer.save(&path).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    let record = buffer.replay().get(&keys[1]).unwrap().obs.compressed();
    let at = bytes
        .windows(record.len())
        .position(|w| w == record)
        .expect("the snapshot holds the compressed bytes as they are");
    bytes[at + record.len() / 2] ^= 0x01;
    std::fs::write(&path, &bytes).unwrap();
    let err = ReplayBuffer::load(&path).unwrap_err().to_string();
    assert!(err.contains("record.snap"), "{err}");
    assert!(
        err.contains("Push ring's observation at slot 1 (episode 0, step 1)"),
        "{err}"
    );
}

#[test]
fn a_batch_travels_packed_and_a_damaged_item_is_named() {
    let config = BufferConfig {
        min_size_to_sample: 1,
        ..config(16)
    };
    let mut buffer = ReplayBuffer::new(config, serving_both()).unwrap();
    for t in non_goal_episode(0) {
        buffer.add_step(t, None).unwrap();
    }
    buffer.end_episode(0, Some(9)).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let batch = buffer.sample(Primitive::Push, 4, &mut rng).unwrap();
    let items = batch.to_owned_items();
    for (owned, lent) in items.iter().zip(&batch.items) {
        assert!(
            owned.transition.obs.shares(&lent.transition.obs),
            "no bytes copied"
        );
    }
    // Through a message's encoding, as the learner receives it.
    let mut bytes = postcard::to_stdvec(&items).unwrap();
    let received: Vec<BatchItem<StoredTransition>> = postcard::from_bytes(&bytes).unwrap();
    let unpacked_items = buffer::unpack(&received).unwrap();
    let episode = non_goal_episode(0);
    for item in &unpacked_items {
        assert_eq!(
            item.transition.obs,
            episode[item.transition.step as usize].obs
        );
    }
    assert_eq!(unpacked_items, batch.unpack().unwrap());

    // A byte of the first item's frame flipped on the way.
    let record = items[0].transition.obs.compressed();
    let at = bytes
        .windows(record.len())
        .position(|w| w == record)
        .expect("the message holds the compressed bytes as they are");
    bytes[at + record.len() / 2] ^= 0x01;
    let received: Vec<BatchItem<StoredTransition>> = postcard::from_bytes(&bytes).unwrap();
    match buffer::unpack(&received) {
        Err(ReplayError::Corrupt { key, why }) => {
            assert_eq!(key, items[0].key);
            assert_eq!(why, experience::CorruptObservation::Hash);
        }
        other => panic!("a damaged item was unpacked: {other:?}"),
    }
}
