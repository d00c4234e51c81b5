//! The CPU inference form against burn's forward: the same Q maps, within 1e-4 of their
//! scale, for every net shape the configs use, on weights and batch-norm statistics moved
//! away from their initial values by training.

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use qnet::{Difference, Geometry, Inference, NetInput, QNetConfig, QNets, RotatedQMaps};
use sim::{Camera, Primitive, SimConfig, Tabletop};

fn scene_input(pixel_size: f32, goal: u8) -> NetInput {
    let (tabletop, _) = Tabletop::random(&SimConfig::with_pixel_size(pixel_size), 5, 3).unwrap();
    let maps = Camera::new(tabletop.grid()).render(&tabletop);
    NetInput::encode(&maps, goal)
}

/// Fresh nets after a few Adam steps on both primitives in training mode: every weight,
/// batch-norm scale and shift, and running statistic differs from its initial value.
fn trained_nets(config: &QNetConfig, geometry: &Geometry, input: &NetInput) -> QNets {
    let device = Device::flex();
    let mut nets = QNets::new(config, &device)
        .to_device(&device.autodiff())
        .train();
    let mut optimiser = AdamConfig::new().init();
    let items = [(input, 2u8), (input, 9u8)];
    for _ in 0..3 {
        for primitive in [Primitive::Push, Primitive::Grasp] {
            let maps = nets.q_maps(primitive, &items, geometry).unwrap();
            let loss = (maps - 0.5).powi_scalar(2).mean();
            let grads = GradientsParams::from_grads(loss.backward(), &nets);
            nets = optimiser.step(0.01, nets, grads);
        }
    }
    nets.valid()
}

fn agrees(config: &QNetConfig, pixel_size: f32) {
    let input = scene_input(pixel_size, 2);
    let geometry = Geometry::new(input.side, config);
    let nets = trained_nets(config, &geometry, &input);
    let inference = Inference::new(&nets).unwrap();
    // What an actor that pushes runs: both nets on each rotated input, which must give
    // exactly the maps of each net run alone.
    let primitives = [Primitive::Push, Primitive::Grasp];
    let both = inference
        .all_rotations_of(primitives, &input, &geometry)
        .unwrap();
    for (primitive, together) in primitives.into_iter().zip(&both) {
        let alone = inference
            .all_rotations(primitive, &input, &geometry)
            .unwrap();
        assert_eq!(
            together.values(),
            alone.values(),
            "{config:?} {primitive:?}"
        );
    }
    for primitive in primitives {
        let want = nets.all_rotations(primitive, &input, &geometry).unwrap();
        let got = inference
            .all_rotations(primitive, &input, &geometry)
            .unwrap();
        assert_eq!(
            (got.rotations(), got.side()),
            (want.rotations(), want.side())
        );
        let d = Difference::between(got.values(), want.values());
        println!(
            "{config:?} at {} px, {primitive:?}: max abs difference {:e}, relative {:e}",
            input.side, d.max_abs, d.max_rel
        );
        assert!(d.max_rel <= 1e-4, "{config:?} {primitive:?}: {d:?}");
    }
}

#[test]
fn the_inference_form_gives_burns_q_maps_for_the_default_net() {
    agrees(&QNetConfig::default(), 0.004);
}

#[test]
fn the_inference_form_gives_burns_q_maps_for_the_stage_nets() {
    // configs/stage*.toml: context convolutions in each trunk; and an outcome head on the
    // grasp net, which the inference form leaves out.
    let config = QNetConfig {
        context_dilations: vec![1, 2],
        grasp_outcome_head: true,
        ..QNetConfig::default()
    };
    agrees(&config, 0.004);
}

#[test]
fn the_inference_form_gives_burns_q_maps_with_fused_context_at_224() {
    // Fused context, and the paper's 2 mm pixels with the dilations of results/archive.md,
    // "Finer heightmaps".
    let config = QNetConfig {
        context_dilations: vec![2, 4],
        fuse_context: true,
        ..QNetConfig::default()
    };
    agrees(&config, 0.002);
}

#[test]
fn the_inference_form_gives_burns_q_maps_for_rotation_equivariant_nets() {
    // Four passes for the sixteen rotations, each scoring four angles; the stage nets'
    // context convolutions and outcome head.
    let config = QNetConfig {
        context_dilations: vec![1, 2],
        grasp_outcome_head: true,
        rotation_equivariant: true,
        ..QNetConfig::default()
    };
    agrees(&config, 0.004);
}

#[test]
fn a_batch_of_inputs_gives_each_input_its_own_q_maps() {
    // Several environments' decisions as one batch (`envs_per_actor`): each input's maps are
    // exactly those it gets alone, in the order given, for a net with four passes too.
    for rotation_equivariant in [false, true] {
        let config = QNetConfig {
            rotation_equivariant,
            ..QNetConfig::default()
        };
        let inputs = [
            scene_input(0.004, 1),
            scene_input(0.004, 3),
            scene_input(0.004, 2),
        ];
        let geometry = Geometry::new(inputs[0].side, &config);
        let nets = trained_nets(&config, &geometry, &inputs[0]);
        let inference = Inference::new(&nets).unwrap();
        let primitives = [Primitive::Push, Primitive::Grasp];
        let batch: Vec<&NetInput> = inputs.iter().collect();
        let each = inference
            .all_rotations_of_each(primitives, &batch, &geometry)
            .unwrap();
        assert_eq!(each.len(), inputs.len());
        for (input, maps) in inputs.iter().zip(&each) {
            let alone = inference
                .all_rotations_of(primitives, input, &geometry)
                .unwrap();
            for (got, want) in maps.iter().zip(&alone) {
                assert_eq!(
                    got.values(),
                    want.values(),
                    "equivariant {rotation_equivariant}"
                );
            }
        }
        // Different goals give different maps: the batch did not hand one input's to all.
        assert_ne!(each[0][1].values(), each[1][1].values());
    }
}

#[test]
fn the_convolutions_alone_give_the_maps_before_the_rotations() {
    // `low_maps` of two rotated inputs equals burn's forward of the same planes.
    let config = QNetConfig::default();
    let input = scene_input(0.004, 1);
    let geometry = Geometry::new(input.side, &config);
    let nets = trained_nets(&config, &geometry, &input);
    let inference = Inference::new(&nets).unwrap();
    let [mut colour, mut depth, mut mask] = [Vec::new(), Vec::new(), Vec::new()];
    for k in [0u8, 5] {
        geometry.rotate_input(&input, k, [&mut colour, &mut depth, &mut mask]);
    }
    let low = inference.low_maps(Primitive::Grasp, [&colour, &depth, &mask], &geometry);
    let area = geometry.low_side() * geometry.low_side();
    assert_eq!(low.len(), 2 * area);
    let device = Device::flex();
    let plane = |values: &[f32], channels: usize| {
        let p = geometry.padded();
        let data = TensorData::new(values.to_vec(), [2, channels, p, p]);
        Tensor::<4>::from_data(data, &device)
    };
    let want = nets
        .grasp
        .forward(plane(&colour, 3), plane(&depth, 1), plane(&mask, 1))
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    let d = Difference::between(&low, &want);
    assert!(d.max_rel <= 1e-4, "{d:?}");
}

#[test]
fn an_input_of_another_size_is_refused() {
    let config = QNetConfig::default();
    let nets = QNets::new(&config, &Device::flex()).valid();
    let inference = Inference::new(&nets).unwrap();
    let error = inference
        .all_rotations(
            Primitive::Grasp,
            &scene_input(0.004, 1),
            &Geometry::new(224, &config),
        )
        .unwrap_err();
    assert!(error.to_string().contains("224"), "{error}");
}
