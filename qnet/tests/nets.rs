//! The nets' shapes, inference over every rotation, and weights round trips.

use burn::module::Module;
use burn::prelude::*;
use qnet::{Geometry, NetInput, QNetConfig, QNets, RotatedQMaps};
use sim::{Camera, Primitive, SimConfig, Tabletop};

fn scene_input(goal: u8) -> NetInput {
    let (tabletop, _) = Tabletop::random(&SimConfig::with_pixel_size(0.004), 5, 3).unwrap();
    let maps = Camera::new(tabletop.grid()).render(&tabletop);
    NetInput::encode(&maps, goal)
}

#[test]
fn q_maps_have_the_heightmaps_shape_for_every_rotation() {
    let config = QNetConfig::default();
    let device = Device::flex();
    let nets = QNets::new(&config, &device).valid();
    let geometry = Geometry::new(112, &config);
    let input = scene_input(1);
    let maps = nets
        .all_rotations(Primitive::Grasp, &input, &geometry)
        .unwrap();
    assert_eq!((maps.rotations(), maps.side()), (16, 112));
    assert!(maps.values().iter().all(|v| v.is_finite()));
    let spread = maps.values().iter().fold(f32::MIN, |a, &b| a.max(b))
        - maps.values().iter().fold(f32::MAX, |a, &b| a.min(b));
    assert!(spread > 0.0, "Q maps vary over the scene");

    let items = [(&input, 3u8), (&input, 11u8)];
    let two = nets.q_maps(Primitive::Push, &items, &geometry).unwrap();
    assert_eq!(two.dims(), [2, 112, 112]);
}

#[test]
fn a_mismatched_input_or_rotation_is_refused() {
    let config = QNetConfig::default();
    let nets = QNets::new(&config, &Device::flex()).valid();
    let geometry = Geometry::new(224, &config);
    let input = scene_input(1);
    let error = nets
        .all_rotations(Primitive::Grasp, &input, &geometry)
        .unwrap_err();
    assert!(error.to_string().contains("112"), "{error}");
    let geometry = Geometry::new(112, &config);
    let error = nets
        .q_maps(Primitive::Grasp, &[(&input, 16)], &geometry)
        .unwrap_err();
    assert!(error.to_string().contains("16"), "{error}");
}

#[test]
fn weights_round_trip_through_bytes_to_identical_q_maps() {
    let config = QNetConfig::default();
    let device = Device::flex();
    let geometry = Geometry::new(112, &config);
    let input = scene_input(2);
    let trained = QNets::new(&config, &device).valid();
    let other = QNets::new(&config, &device).valid();
    let want = trained
        .all_rotations(Primitive::Grasp, &input, &geometry)
        .unwrap();
    let before = other
        .all_rotations(Primitive::Grasp, &input, &geometry)
        .unwrap();
    assert_ne!(want, before, "two initialisations differ");

    let bytes = trained.to_bytes().unwrap();
    let loaded = other.load_bytes(&bytes).unwrap();
    assert_eq!(
        loaded
            .all_rotations(Primitive::Grasp, &input, &geometry)
            .unwrap(),
        want
    );
    let push = |nets: &QNets| {
        nets.all_rotations(Primitive::Push, &input, &geometry)
            .unwrap()
    };
    assert_eq!(push(&loaded), push(&trained));

    let error = QNets::new(&config, &device)
        .load_bytes(&bytes[..bytes.len() / 2])
        .unwrap_err();
    assert!(error.to_string().contains("weights"), "{error}");
}

/// How far (in pixels along a row) a change of the goal mask reaches into rotation 0's
/// Q map around pixel (56, 56).
fn reach(config: &QNetConfig) -> usize {
    let nets = QNets::new(config, &Device::flex()).valid();
    let geometry = Geometry::new(112, config);
    let q = |input: &NetInput| {
        let maps = nets.q_maps(Primitive::Grasp, &[(input, 0)], &geometry);
        maps.unwrap().into_data().try_to_vec::<f32>().unwrap()[56 * 112 + 56]
    };
    let plain = NetInput {
        side: 112,
        colour: vec![0.0; 3 * 112 * 112],
        depth: vec![0.0; 112 * 112],
        mask: vec![0.0; 112 * 112],
    };
    let base = q(&plain);
    (1..56)
        .filter(|&distance| {
            let mut marked = plain.clone();
            marked.mask[56 * 112 + 56 + distance] = 1.0;
            q(&marked) != base
        })
        .max()
        .unwrap_or(0)
}

#[test]
fn context_dilations_widen_what_a_q_value_sees() {
    let local = QNetConfig {
        context_dilations: Vec::new(),
        ..QNetConfig::default()
    };
    let wide = QNetConfig {
        context_dilations: vec![1, 2],
        ..QNetConfig::default()
    };
    let fused = QNetConfig {
        fuse_context: true,
        ..wide.clone()
    };
    let (near, far) = (reach(&local), reach(&wide));
    // Two stride-2 layers see 3 pixels to each side; [1, 2] at stride 4 adds (1 + 2) x 4.
    assert!(near > 0 && near <= 4, "reach without context: {near}");
    assert!(
        far >= near + 12,
        "reach with context: {far} (without: {near})"
    );
    // Context convolutions over the trunks together widen it as far. Not equal to `far`:
    // each net draws its own weights, and a unit dead at the field's rim shortens a reach by
    // a pixel now and then (14 against 15 seen once).
    let fused = reach(&fused);
    assert!(
        fused >= near + 12,
        "reach with fused context: {fused} (without: {near})"
    );
}

#[test]
fn a_net_in_training_gives_the_q_maps_of_the_same_net_frozen() {
    // A net whose weights take gradients convolves by GEMM (for its fast weight gradients),
    // a frozen one by burn's conv2d: one function either way, every layer kind included.
    for fuse_context in [false, true] {
        let config = QNetConfig {
            context_dilations: vec![1, 2],
            fuse_context,
            ..QNetConfig::default()
        };
        training_and_frozen_agree(&config);
    }
}

fn training_and_frozen_agree(config: &QNetConfig) {
    // As the learner holds them: on the autodiff device, in training.
    let device = Device::flex();
    let training = QNets::new(config, &device)
        .to_device(&device.autodiff())
        .train();
    let frozen = training.clone().no_grad();
    let geometry = Geometry::new(112, config);
    let input = scene_input(2);
    let items = [(&input, 3u8), (&input, 11u8)];
    let maps = |nets: &QNets| {
        nets.q_maps(Primitive::Grasp, &items, &geometry)
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap()
    };
    let (a, b) = (maps(&training), maps(&frozen));
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
    let worst = a
        .iter()
        .zip(&b)
        .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
    assert!(
        scale > 0.0 && worst <= 1e-4 * scale,
        "differ by {worst} of {scale}"
    );
}
