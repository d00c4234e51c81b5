//! Tests of the primitive nets: fresh heads, equivariance, and the CPU's own convolution and
//! batch norm beside burn's.

use burn::tensor::Distribution;
use burn::tensor::activation::relu;

use super::ops::conv_as_gemm;
use super::*;
use crate::batch_norm;
use crate::testing::assert_close;

/// `conv`'s output at `x` and the gradients of `sum(y^2) / 2` (so each output pixel's
/// gradient is its own value): input, weight, bias.
fn output_and_gradients(
    conv: &Conv2d,
    x: &Tensor<4>,
    run: fn(&Conv2d, Tensor<4>) -> Tensor<4>,
) -> [Vec<f32>; 4] {
    let x = x.clone().require_grad();
    let y = run(conv, x.clone());
    let grads = (y.clone() * y.clone()).sum().mul_scalar(0.5).backward();
    let values = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
    let bias = conv
        .bias
        .as_ref()
        .expect("a bias")
        .val()
        .grad(&grads)
        .unwrap();
    [
        values(y),
        values(x.grad(&grads).unwrap()),
        values(conv.weight.val().grad(&grads).unwrap()),
        bias.into_data().try_to_vec::<f32>().unwrap(),
    ]
}

#[test]
fn a_fresh_head_keeps_the_trunks_and_redraws_the_head() {
    let device = Device::flex();
    let config = QNetConfig {
        context_dilations: vec![1],
        fuse_context: true,
        ..QNetConfig::default()
    };
    let net = PrimitiveNet::new(&config, true, &device);
    let values = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
    let trunk = |net: &PrimitiveNet| {
        [&net.colour, &net.depth, &net.mask, &net.fused]
            .map(|trunk| values(trunk.blocks[0].conv.weight.val()))
    };
    let outputs = |net: &PrimitiveNet| {
        let outcome = net.outcome_out.as_ref().expect("an outcome head");
        [&net.head_out, outcome].map(|conv| values(conv.weight.val()))
    };
    let before = (trunk(&net), outputs(&net));
    let mut fresh = net.clone();
    fresh.fresh_head(&config, &device);
    assert_eq!(trunk(&fresh), before.0);
    for (after, before) in outputs(&fresh).iter().zip(&before.1) {
        assert_ne!(after, before);
    }
    let x = |channels| Tensor::<4>::ones([1, channels, 16, 16], &device);
    assert_eq!(fresh.forward(x(3), x(1), x(1)).dims(), [1, 1, 4, 4]);
    let both = fresh.forward_with_outcome(x(3), x(1), x(1));
    assert_eq!(both.dims(), [1, 2, 4, 4]);
    assert_eq!(
        values(both.slice([0..1, 0..1])),
        values(fresh.forward(x(3), x(1), x(1)))
    );
}

#[test]
fn an_equivariant_net_turns_its_maps_with_its_input_and_shifts_their_angles() {
    // Channel g scores the action g quarter turns on: the input turned a quarter turn
    // gives each map turned, one angle on. Exact on sides that stay odd down the
    // strides (17, 9, 5), in training (batch statistics shared within a field) and
    // frozen, and the same function as the net laid out in full.
    let config = QNetConfig {
        trunk_widths: vec![4, 8],
        context_dilations: vec![1],
        head_width: 8,
        rotation_equivariant: true,
        ..QNetConfig::default()
    };
    let device = Device::flex();
    let net = PrimitiveNet::new(&config, false, &device);
    let input = |c| Tensor::<4>::random([2, c, 17, 17], Distribution::Default, &device);
    let planes = [input(3), input(1), input(1)];
    let turn = crate::equivariant::quarter_turn::<4, Float>;
    let values = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
    let forward = |net: &PrimitiveNet, turned: bool| {
        let on = net.devices()[0].clone();
        let [c, d, m] = planes.clone().map(|x| {
            let x = x.to_device(&on);
            if turned { turn(x) } else { x }
        });
        net.forward(c, d, m)
    };
    let check = |net: &PrimitiveNet, what: &str| {
        let y = forward(net, false);
        assert_eq!(y.dims(), [2, 4, 5, 5]);
        let expected = turn(y).roll_dim(1, 1);
        assert_close(&values(forward(net, true)), &values(expected), 1e-4, what);
    };
    let training = net.to_device(&device.autodiff()).train();
    check(&training, "in training");
    let frozen = training.valid();
    check(&frozen, "frozen");
    let ordinary = frozen.expanded();
    assert_eq!(ordinary.group(), 1);
    assert_eq!(
        [ordinary.angles_per_pass(), frozen.angles_per_pass()],
        [4, 4]
    );
    assert_close(
        &values(forward(&ordinary, false)),
        &values(forward(&frozen, false)),
        1e-5,
        "laid out in full",
    );
}

#[test]
fn the_gemm_convolution_and_its_gradients_equal_burns_conv2d() {
    let device = Device::flex().autodiff();
    for (stride, dilation) in [(2, 1), (1, 1), (1, 2)] {
        let mut conv = ConvBlock::new([3, 5], stride, dilation, [1, 1], &device).conv;
        // A block's convolution has none, the head's last has one: test with one.
        let bias = Tensor::<1>::random([5], Distribution::Default, &device);
        conv.bias = Some(burn::module::Param::from_tensor(bias));
        let x = Tensor::<4>::random([2, 3, 12, 12], Distribution::Default, &device);
        let ours = output_and_gradients(&conv, &x, |conv, x| {
            let bias = conv.bias.as_ref().map(|bias| bias.val());
            conv_as_gemm(conv, conv.weight.val(), bias, x)
        });
        let burns = output_and_gradients(&conv, &x, |conv, x| conv.forward(x));
        for (what, (a, b)) in ["output", "input grad", "weight grad", "bias grad"]
            .iter()
            .zip(ours.iter().zip(&burns))
        {
            let what = format!("stride {stride}, dilation {dilation}: {what}");
            assert_close(a, b, 1e-5, &what);
        }
    }
}

#[test]
fn batch_norm_and_relu_in_training_equal_burns_output_gradients_and_running_statistics() {
    let device = Device::flex().autodiff();
    let x = Tensor::<4>::random([3, 5, 7, 7], Distribution::Default, &device).mul_scalar(3.0);
    let run = |ours: bool| {
        let norm = BatchNormConfig::new(5).init(&device);
        let forward = |x: Tensor<4>| match ours {
            true => batch_norm::forward_relu(&norm, x),
            false => relu(norm.forward(x)),
        };
        // A pass before, so the running statistics are moved twice, the second time from
        // what the first left.
        let _ = forward(x.clone().mul_scalar(0.5).add_scalar(1.0));
        let x = x.clone().require_grad();
        let y = forward(x.clone());
        // A loss whose gradient differs per pixel, so every term of the backward counts,
        // and is not zero where the ReLU cut the value, so its mask counts too.
        let grads = (y.clone() * (y.clone() + x.clone().detach()))
            .sum()
            .backward();
        let values4 = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
        let values1 = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap();
        [
            values4(y),
            values4(x.grad(&grads).unwrap()),
            values1(norm.gamma.val().grad(&grads).unwrap()),
            values1(norm.beta.val().grad(&grads).unwrap()),
            values1(norm.running_mean.value_sync()),
            values1(norm.running_var.value_sync()),
        ]
    };
    let (ours, burns) = (run(true), run(false));
    let parts = [
        "output",
        "input grad",
        "gamma grad",
        "beta grad",
        "running mean",
        "running var",
    ];
    for ((what, a), b) in parts.iter().zip(&ours).zip(&burns) {
        assert_close(a, b, 1e-4, what);
    }
}
