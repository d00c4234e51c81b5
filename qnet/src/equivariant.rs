//! Quarter-turn (C4) equivariance: convolutions whose weights are tied across the four
//! rotations by 90 degrees (group convolutions, Cohen and Welling 2016), so one pass of a net
//! scores four action angles at once (Wang, Walters and Platt 2022 build the same symmetry
//! into Q maps over rotated actions).
//!
//! A feature of such a net is a field of `group` channels, one per quarter turn, side by side
//! (channel `f * group + g`). Channel `g` of a net's output is the map it would give for the
//! input turned by `-g` quarter turns, turned back: with [`quarter_turn`] as rho,
//! `f_g(x) = rho^g f_0(rho^-g x)`. Each convolution holds one base kernel per output field;
//! [`expand`] lays out the full weights, each output rotation `g` being the base kernel turned
//! `g` quarter turns with its input rotations shifted by `g`. Batch norms share their
//! statistics and affine values within a field ([`fields`]). `group` 1 is an ordinary net.

use std::sync::Mutex;

use burn::prelude::*;
use burn::tensor::kind::Basic;
use sim::ROTATIONS;

use crate::weight_layout::{FROM_CHANNELS_LAST, TO_CHANNELS_LAST};

/// The rotations by 90 degrees.
pub const QUARTER_TURNS: usize = 4;

/// The map `x` (its last two dimensions, square) turned by one quarter turn, the way the
/// nets' input rotation turns it back for rotation index `ROTATIONS / 4` (+90 degrees):
/// `out[r][c] = x[S - 1 - c][r]`.
pub fn quarter_turn<const D: usize, K: Basic>(x: Tensor<D, K>) -> Tensor<D, K> {
    x.flip([D - 2]).swap_dims(D - 2, D - 1)
}

/// `x` turned by `turns` quarter turns.
pub fn quarter_turns<const D: usize, K: Basic>(x: Tensor<D, K>, turns: usize) -> Tensor<D, K> {
    (0..turns % QUARTER_TURNS).fold(x, |x, _| quarter_turn(x))
}

/// The full weights `[fields_out * groups[1], channels_in, k, k]` of a convolution from
/// features of `groups[0]` channels a field (1: plain input planes) to `groups[1]`, from its
/// base kernels `[fields_out, channels_in, k, k]` (`channels_in` = fields in x `groups[0]`):
/// output rotation `g` is the base turned by `g` quarter turns, its input rotations
/// shifted by `g` (`laid_out`). With `groups[1]` 1 the base itself.
///
/// Each output field's weights are the same rearrangement of its base kernel's, so they
/// are gathered in one selection by an index worked out once (`expansion_index`): a
/// training step's every convolution lays its weights out anew, and the quarter turns and
/// shifts one by one were about twenty kernels a convolution on a GPU, their gradients as
/// many again (an equivariant stage step on lavapipe: 1,070 kernels so, 627 gathered).
///
/// On a GPU the gather is channels-last, `[k, k, channels_in]` a kernel in memory: base
/// kernels held so (a trainer's, `QNets::with_weights_channels_last`) are read as they lie,
/// and the full kernels come out laid out as the convolution reads them. Laid out as burn
/// lays them out, the base would be copied before the gather, or the full kernels before
/// the convolution and its input's gradient.
pub fn expand(base: Tensor<4>, groups: [usize; 2]) -> Tensor<4> {
    if groups[1] == 1 {
        return base;
    }
    let [fields_out, channels_in, k, _] = base.dims();
    let channels_last = base.device() != Device::flex();
    let index = expansion_index([channels_in, k], groups, channels_last, &base.device());
    if channels_last {
        base.permute(TO_CHANNELS_LAST)
            .reshape([fields_out, k * k * channels_in])
            .select(1, index)
            .reshape([fields_out * groups[1], k, k, channels_in])
            .permute(FROM_CHANNELS_LAST)
    } else {
        base.reshape([fields_out, channels_in * k * k])
            .select(1, index)
            .reshape([fields_out * groups[1], channels_in, k, k])
    }
}

/// The indices within one base kernel (`channels_in x k x k`, `[channels_in, k]` in
/// `shape`, its values laid out channels-last where `channels_last`) that [`expand`]
/// gathers, in the order its full kernels lie, as a tensor on `device`: [`laid_out`] of the
/// numbered kernel, worked out on the CPU once per shape, layout and device.
fn expansion_index(
    shape: [usize; 2],
    groups: [usize; 2],
    channels_last: bool,
    device: &Device,
) -> Tensor<1, Int> {
    // Devices compare equal with autodiff on and off: whether it is on is part of the key.
    type Key = ([usize; 2], [usize; 2], bool, Device, bool);
    static KNOWN: Mutex<Vec<(Key, Tensor<1, Int>)>> = Mutex::new(Vec::new());
    let key = (
        shape,
        groups,
        channels_last,
        device.clone(),
        device.is_autodiff(),
    );
    let mut known = KNOWN
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some((_, index)) = known.iter().find(|(k, _)| *k == key) {
        return index.clone();
    }
    let [channels_in, k] = shape;
    let n = channels_in * k * k;
    // Each value of a base kernel `[1, channels_in, k, k]` numbered by where it lies.
    let numbered = Tensor::<1, Int>::arange(0..n as i64, &Device::flex());
    let full = if channels_last {
        let numbered = numbered
            .reshape([1, k, k, channels_in])
            .permute(FROM_CHANNELS_LAST);
        laid_out(numbered, groups).permute(TO_CHANNELS_LAST)
    } else {
        laid_out(numbered.reshape([1, channels_in, k, k]), groups)
    };
    let order: Tensor<1, Int> = full.reshape([n * groups[1]]);
    let index = Tensor::from_data(order.into_data(), device);
    known.push((key, index.clone()));
    index
}

/// [`expand`]'s layout written out, one output rotation at a time.
fn laid_out<K: Basic>(base: Tensor<4, K>, groups: [usize; 2]) -> Tensor<4, K> {
    let [group_in, group_out] = groups;
    let [fields_out, channels_in, k, _] = base.dims();
    let fields_in = channels_in / group_in;
    let base = base.reshape([fields_out, fields_in, group_in, k, k]);
    let rotations: Vec<Tensor<5, K>> = (0..group_out)
        .map(|g| {
            let shifted = base.clone().roll_dim(g % group_in, 2);
            quarter_turns(shifted, g).reshape([fields_out, 1, channels_in, k, k])
        })
        .collect();
    Tensor::cat(rotations, 1).reshape([fields_out * group_out, channels_in, k, k])
}

/// Per-field values `[fields]` (a batch norm's, a bias) given to each of the field's `group`
/// channels: `[fields * group]`.
pub fn per_channel(values: Tensor<1>, group: usize) -> Tensor<1> {
    if group == 1 {
        return values;
    }
    let [fields] = values.dims();
    values
        .reshape([fields, 1])
        .repeat_dim(1, group)
        .reshape([fields * group])
}

/// `x` `[n, fields * group, h, w]` seen as `[n, fields, group * h, w]`: one channel a field,
/// its rotations stacked along the rows, so a batch norm over it shares each field's
/// statistics across its rotations ([`unfields`] undoes it).
pub fn fields(x: Tensor<4>, group: usize) -> Tensor<4> {
    let [n, channels, h, w] = x.dims();
    x.reshape([n, channels / group, group * h, w])
}

/// [`fields`] undone.
pub fn unfields(x: Tensor<4>, group: usize) -> Tensor<4> {
    let [n, fields, rows, w] = x.dims();
    x.reshape([n, fields * group, rows / group, w])
}

/// Which pass over the input serves rotation index `rotation` and which of its output
/// channels holds that rotation's map: a net of `group` rotations a field scores
/// `ROTATIONS / group` input rotations, each for `group` action angles a quarter turn apart.
pub fn pass_and_channel(rotation: u8, group: usize) -> (u8, usize) {
    let passes = (ROTATIONS as usize / group) as u8;
    (rotation % passes, (rotation / passes) as usize)
}

#[cfg(test)]
mod tests {
    use burn::tensor::Distribution;
    use burn::tensor::module::conv2d;
    use burn::tensor::ops::ConvOptions;

    use super::*;
    use crate::testing::assert_close;

    fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    #[test]
    fn a_quarter_turn_moves_the_top_row_to_the_right_column_and_four_return() {
        let device = Device::flex();
        let x = Tensor::<2>::from_data([[1.0, 2.0], [3.0, 4.0]], &device);
        assert_eq!(values(quarter_turn(x.clone())), [3.0, 1.0, 4.0, 2.0]);
        assert_eq!(values(quarter_turns(x.clone(), 4)), values(x));
        // `expand` shifts rotations by rolling: element i moves to i + 1.
        let rolled = Tensor::<1>::from_data([1.0, 2.0, 3.0, 4.0], &device).roll_dim(1, 0);
        assert_eq!(values(rolled), [4.0, 1.0, 2.0, 3.0]);
    }

    #[test]
    fn expanded_convolutions_turn_with_their_input_and_shift_their_rotations() {
        // A lifting layer (plain planes in) then a group layer: turning the input by a
        // quarter turn turns each output map and moves rotation g's map to g + 1.
        // Odd sides keep the stride-2 grid centred, so the symmetry is exact.
        let device = Device::flex();
        let x = Tensor::<4>::random([2, 3, 9, 9], Distribution::Default, &device);
        let lift = Tensor::<4>::random([2, 3, 3, 3], Distribution::Default, &device);
        let group = Tensor::<4>::random([3, 2 * 4, 3, 3], Distribution::Default, &device);
        let net = |x: Tensor<4>| {
            let options = ConvOptions::new([2, 2], [1, 1], [1, 1], 1);
            let y = conv2d(x, expand(lift.clone(), [1, 4]), None, options.clone());
            conv2d(y, expand(group.clone(), [4, 4]), None, options)
        };
        let turned = net(quarter_turn(x.clone()));
        let [n, channels, h, w] = turned.dims();
        let expected = quarter_turn(net(x))
            .reshape([n, channels / 4, 4, h, w])
            .roll_dim(1, 2)
            .reshape([n, channels, h, w]);
        assert_close(&values(turned), &values(expected), 1e-5, "turned output");
    }

    #[test]
    fn gathered_weights_and_their_gradients_are_those_of_the_layout_written_out() {
        // A lifting layer and a group layer; the gradient sums each base weight's four
        // copies, weighted differently.
        let device = Device::flex().autodiff();
        for (groups, shape) in [([1, 4], [2, 3, 3, 3]), ([4, 4], [3, 8, 3, 3])] {
            let base = Tensor::<4>::random(shape, Distribution::Default, &device).require_grad();
            let [fields, channels, k, _] = shape;
            let scale =
                Tensor::<4>::random([fields * 4, channels, k, k], Distribution::Default, &device);
            let run = |full: Tensor<4>| {
                let grads = (full.clone() * scale.clone()).sum().backward();
                let grad = base.grad(&grads).unwrap().flatten::<1>(0, 3);
                [values(full), grad.into_data().try_to_vec::<f32>().unwrap()]
            };
            let [full, grad] = run(expand(base.clone(), groups));
            let [by_ops, grad_by_ops] = run(laid_out(base.clone(), groups));
            assert_eq!(full, by_ops, "{groups:?}: weights");
            assert_close(&grad, &grad_by_ops, 1e-6, "gradient");
        }
    }

    #[test]
    fn shared_statistics_see_a_field_as_one_channel() {
        let device = Device::flex();
        let x = Tensor::<4>::random([2, 8, 3, 5], Distribution::Default, &device);
        let seen = fields(x.clone(), 4);
        assert_eq!(seen.dims(), [2, 2, 12, 5]);
        // Field 1's second rotation is rows 3..6 of its one channel.
        assert_eq!(
            values(seen.clone().slice([0..2, 1..2, 3..6])),
            values(x.clone().slice([0..2, 5..6]))
        );
        assert_eq!(values(unfields(seen, 4)), values(x));
        let per = per_channel(Tensor::<1>::from_data([1.0, 2.0], &device), 4);
        assert_eq!(values(per), [1.0, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0]);
    }

    #[test]
    fn four_rotations_a_field_serve_sixteen_angles_from_four_passes() {
        assert_eq!(pass_and_channel(6, 1), (6, 0));
        assert_eq!(pass_and_channel(6, 4), (2, 1));
        assert_eq!(pass_and_channel(15, 4), (3, 3));
    }
}
