//! Tests of the two nets together: values at pixels, passes over rotations, and their weights
//! as bytes.

use burn::module::Param;
use burn::tensor::Distribution;

use super::*;
use crate::testing::{assert_close, patterned_input};

#[test]
fn values_at_pixels_and_their_gradients_are_the_full_maps_at_those_pixels() {
    let side = 24;
    let input = patterned_input(side);
    // The corners and edges (the upsampling and the rotation back clamp there) and
    // rotations in every quadrant.
    let rotations = [0u8, 3, 5, 8, 13, 15];
    let pixels = [(0, 0), (23, 23), (5, 17), (12, 0), (23, 6), (11, 11)];
    let items: Vec<(&NetInput, u8)> = rotations.iter().map(|&k| (&input, k)).collect();
    for rotation_equivariant in [false, true] {
        let config = QNetConfig {
            trunk_widths: vec![4, 8],
            head_width: 8,
            grasp_outcome_head: true,
            rotation_equivariant,
            ..QNetConfig::default()
        };
        let device = Device::flex().autodiff();
        let nets = QNets::new(&config, &device).train();
        let geometry = Geometry::new(side, &config);
        let what = |part: &str| format!("equivariant {rotation_equivariant}: {part}");
        let coefficients = |offset| {
            Tensor::<1>::random([items.len()], Distribution::Default, &device).add_scalar(offset)
        };
        let (a, b) = (coefficients(0.5), coefficients(1.0));
        // What the learner differentiated before: the full maps masked at the pixels.
        let (maps, logits) = nets
            .q_and_outcome_maps(Primitive::Grasp, &items, &geometry)
            .unwrap();
        let mut one_hot = vec![0.0; items.len() * side * side];
        for (j, &(row, col)) in pixels.iter().enumerate() {
            one_hot[(j * side + row) * side + col] = 1.0;
        }
        let one_hot =
            Tensor::<3>::from_data(TensorData::new(one_hot, [items.len(), side, side]), &device);
        let pick = |maps: Tensor<3>| {
            (maps * one_hot.clone())
                .sum_dim(2)
                .sum_dim(1)
                .flatten::<1>(0, 2)
        };
        let full = (pick(maps), pick(logits.unwrap()));
        let direct = nets
            .at_pixels(Primitive::Grasp, &items, &pixels, &geometry)
            .unwrap();
        let direct = (direct.0, direct.1.unwrap());
        let values = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap();
        assert_close(
            &values(direct.0.clone()),
            &values(full.0.clone()),
            1e-5,
            &what("Q"),
        );
        assert_close(
            &values(direct.1.clone()),
            &values(full.1.clone()),
            1e-5,
            &what("logit"),
        );
        let loss = |(q, logit): (Tensor<1>, Tensor<1>)| (q * a.clone() + logit * b.clone()).sum();
        let (direct, full) = (loss(direct).backward(), loss(full).backward());
        let net = &nets.grasp;
        let outcome = net.outcome_out.as_ref().unwrap();
        for (part, weight) in [
            (
                "the trunk's first convolution",
                &net.colour.blocks[0].conv.weight,
            ),
            ("the Q output", &net.head_out.weight),
            ("the outcome output", &outcome.weight),
        ] {
            let grad = |grads| values(weight.val().grad(grads).unwrap().flatten::<1>(0, 3));
            assert_close(&grad(&direct), &grad(&full), 1e-4, &what(part));
        }
    }
}

#[test]
fn an_equivariant_pass_asked_for_all_its_channels_in_order_gives_one_map_per_item() {
    let side = 16;
    let input = patterned_input(side);
    let config = QNetConfig {
        trunk_widths: vec![4, 8],
        head_width: 8,
        rotation_equivariant: true,
        ..QNetConfig::default()
    };
    let nets = QNets::new(&config, &Device::flex());
    let geometry = Geometry::new(side, &config);
    // Rotations a quarter turn apart: one pass, its four channels in order.
    let together = nets
        .rotations(Primitive::Grasp, &input, &[0, 4, 8, 12], &geometry)
        .unwrap();
    let apart: Vec<f32> = [0u8, 4, 8, 12]
        .iter()
        .flat_map(|&k| {
            nets.rotations(Primitive::Grasp, &input, &[k], &geometry)
                .unwrap()
        })
        .collect();
    assert_eq!(together.len(), 4 * side * side);
    assert_close(&together, &apart, 1e-5, "four channels of one pass");
}

#[test]
fn every_rotation_of_several_inputs_in_one_pass_gives_each_inputs_own_maps() {
    let side = 16;
    let (a, b) = (patterned_input(side), patterned_input(side).mirrored());
    let config = QNetConfig {
        trunk_widths: vec![4, 8],
        head_width: 8,
        ..QNetConfig::default()
    };
    let nets = QNets::new(&config, &Device::flex());
    let geometry = Geometry::new(side, &config);
    let primitives = [Primitive::Push, Primitive::Grasp];
    let together = nets
        .all_rotations_of_each(primitives, &[&a, &b], &geometry)
        .unwrap();
    assert_eq!(together.len(), 2);
    for (maps, input) in together.iter().zip([&a, &b]) {
        for (maps, primitive) in maps.iter().zip(primitives) {
            let alone = nets.all_rotations(primitive, input, &geometry).unwrap();
            assert_close(maps.values(), alone.values(), 1e-5, "one input's maps");
        }
    }
    assert_ne!(together[0][1].values(), together[1][1].values());
}

#[test]
fn nets_copied_in_one_read_save_the_bytes_they_were_read_from() {
    let device = Device::flex();
    let config = QNetConfig {
        context_dilations: vec![1, 2],
        grasp_outcome_head: true,
        ..QNetConfig::default()
    };
    let nets = QNets::new(&config, &device);
    // As a trainer holds them: on the autodiff device, in training form.
    let trained = nets.clone().to_device(&device.clone().autodiff()).train();
    let copy = copied_to(&trained, &device);
    assert!(!copy.device().is_autodiff());
    assert_eq!(copy.to_bytes().unwrap(), nets.to_bytes().unwrap());
    // The nets copied from are left as they were, batch norms' running statistics too
    // (which a module's clones share).
    let mut left = AllAutodiff(true);
    trained.visit(&mut left);
    assert!(left.0, "a tensor of the nets copied from moved");
}

/// Whether every float tensor of a module is on an autodiff device.
struct AllAutodiff(bool);

impl burn::module::ModuleVisitor for AllAutodiff {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        self.0 &= param.val().device().is_autodiff();
    }
}

#[test]
fn weights_with_biases_before_a_batch_norm_are_refused_saying_why() {
    let (config, device) = (QNetConfig::default(), Device::flex());
    let mut older = QNets::new(&config, &device);
    // What an older pushgrasp saved: its blocks' convolutions had biases.
    let conv = &mut older.grasp.colour.blocks[0].conv;
    let channels = conv.weight.dims()[0];
    conv.bias = Some(Param::from_tensor(Tensor::<1>::zeros([channels], &device)));
    let bytes = older.to_bytes().unwrap();
    let err = QNets::new(&config, &device)
        .load_bytes(&bytes)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("grasp.colour.blocks.0.conv.bias") && err.contains("older pushgrasp"),
        "{err}"
    );
}
