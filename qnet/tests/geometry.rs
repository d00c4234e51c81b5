//! The rotation contract: rotation k turns the action direction at angle k x 22.5 degrees
//! into +x before the nets, and the back-rotation puts each Q value where its action is.

use burn::prelude::*;
use burn::tensor::ops::{GridSampleOptions, GridSamplePaddingMode, InterpolateMode};
use qnet::{Geometry, NetInput, QNetConfig};
use sim::rotation_angle as angle;

const SIDE: usize = 112;

/// An input of bare table with one marked depth pixel.
fn marked(row: usize, col: usize) -> NetInput {
    let n = SIDE * SIDE;
    let table = NetInput::table_values();
    let mut input = NetInput {
        side: SIDE,
        colour: (0..3).flat_map(|c| vec![table[c]; n]).collect(),
        depth: vec![table[3]; n],
        mask: vec![0.0; n],
    };
    input.depth[row * SIDE + col] = 100.0;
    input
}

#[test]
fn padding_keeps_every_corner_and_divides_by_the_trunks() {
    for (side, want) in [(112, 160), (224, 320)] {
        let geometry = Geometry::new(side, &QNetConfig::default());
        assert_eq!(geometry.padded(), want);
        assert_eq!(geometry.low_side() * 4, want);
        assert!(geometry.padded() as f32 >= side as f32 * std::f32::consts::SQRT_2);
    }
}

#[test]
fn a_marker_at_angle_k_lands_on_plus_x_after_the_input_rotation() {
    let geometry = Geometry::new(SIDE, &QNetConfig::default());
    let p = geometry.padded();
    let centre = SIDE as f32 / 2.0;
    let radius = 30.0;
    for k in 0..16u8 {
        let (sin, cos) = angle(k).sin_cos();
        let col = (centre + radius * cos - 0.5).round() as usize;
        let row = (centre + radius * sin - 0.5).round() as usize;
        let [colour, depth, mask] = {
            let [mut c, mut d, mut m] = [Vec::new(), Vec::new(), Vec::new()];
            geometry.rotate_input(&marked(row, col), k, [&mut c, &mut d, &mut m]);
            [c, d, m]
        };
        assert_eq!(
            (colour.len(), depth.len(), mask.len()),
            (3 * p * p, p * p, p * p)
        );
        let at = depth
            .iter()
            .position(|&v| v == 100.0)
            .expect("the marker survives");
        let (r, c) = ((at / p) as f32 + 0.5, (at % p) as f32 + 0.5);
        let pc = p as f32 / 2.0;
        assert!(
            (c - (pc + radius)).abs() <= 1.5,
            "k {k}: marker at col {c}, row {r}"
        );
        assert!((r - pc).abs() <= 1.5, "k {k}: marker at col {c}, row {r}");
    }
}

#[test]
fn the_back_rotation_puts_a_rotated_frame_marker_at_the_actions_angle() {
    let geometry = Geometry::new(SIDE, &QNetConfig::default());
    let s = geometry.low_side();
    let device = Device::flex();
    for k in 0..16u8 {
        // A marker 8 low-resolution pixels right of the centre of the rotated frame...
        let mut low = vec![0.0f32; s * s];
        low[(s / 2) * s + s / 2 + 8] = 1.0;
        let low = Tensor::<4>::from_data(TensorData::new(low, [1, 1, s, s]), &device);
        let grid = Tensor::<4>::from_data(
            TensorData::new(geometry.back_grid(&[k]), [1, s, s, 2]),
            &device,
        );
        let back = low
            .grid_sample_2d(
                grid,
                GridSampleOptions::new(InterpolateMode::Bilinear)
                    .with_padding_mode(GridSamplePaddingMode::Zeros)
                    .with_align_corners(false),
            )
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        // ...comes back 8 pixels from the centre along the action's direction.
        let (mut wsum, mut x, mut y) = (0.0, 0.0, 0.0);
        for (i, v) in back.iter().enumerate() {
            wsum += v;
            x += v * ((i % s) as f32 + 0.5);
            y += v * ((i / s) as f32 + 0.5);
        }
        let (x, y) = (x / wsum - s as f32 / 2.0, y / wsum - s as f32 / 2.0);
        let (sin, cos) = angle(k).sin_cos();
        let (wx, wy) = (8.5 * cos, 8.5 * sin);
        assert!(
            (x - wx).hypot(y - wy) < 1.0,
            "k {k}: ({x}, {y}) vs ({wx}, {wy})"
        );
    }
}

#[test]
fn the_input_rotation_a_quarter_turn_on_is_the_equivariant_nets_quarter_turn() {
    // A rotation-equivariant net scores rotation k + 4 from rotation k's input turned by
    // `equivariant::quarter_turn`: that must be the input rotation's own step of 90 degrees.
    let geometry = Geometry::new(SIDE, &QNetConfig::default());
    let p = geometry.padded();
    let device = Device::flex();
    let mut input = marked(20, 70);
    input.mask[50 * SIDE + 30] = 1.0;
    let planes = |k: u8| {
        let [mut c, mut d, mut m] = [Vec::new(), Vec::new(), Vec::new()];
        geometry.rotate_input(&input, k, [&mut c, &mut d, &mut m]);
        [(c, 3), (d, 1), (m, 1)].map(|(values, channels)| {
            Tensor::<3>::from_data(TensorData::new(values, [channels, p, p]), &device)
        })
    };
    for k in 0..4u8 {
        for (turned, before) in planes(k + 4).into_iter().zip(planes(k)) {
            let turned = qnet::equivariant::quarter_turn(turned);
            assert_eq!(
                turned.into_data().try_to_vec::<f32>().unwrap(),
                before.into_data().try_to_vec::<f32>().unwrap(),
                "rotation {k}"
            );
        }
    }
}
