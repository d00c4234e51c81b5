//! QMaps: the [rotation][row][col] layout, and the masked argmax the policy builds on.

use policy::{PolicyError, QMaps};

/// Two rotations of 3 x 3 whose values are their own flat index.
fn counting() -> QMaps {
    QMaps::new(2, 3, (0..18).map(|i| i as f32).collect()).unwrap()
}

#[test]
fn the_constructor_checks_the_length() {
    for len in [17, 19, 0] {
        match QMaps::new(2, 3, vec![0.0; len]) {
            Err(PolicyError::QMapsLength { expected, got, .. }) => {
                assert_eq!((expected, got), (18, len));
            }
            other => panic!("{len} values: {other:?}"),
        }
    }
    let maps = QMaps::new(2, 3, vec![0.0; 18]).unwrap();
    assert_eq!(
        (maps.rotations(), maps.side(), maps.values().len()),
        (2, 3, 18)
    );
}

#[test]
fn values_are_laid_out_rotation_then_row_then_column() {
    let maps = counting();
    for rotation in 0..2u8 {
        for row in 0..3 {
            for col in 0..3 {
                let want = (rotation as usize * 9 + row * 3 + col) as f32;
                assert_eq!(
                    maps.get(rotation, row, col),
                    want,
                    "({rotation}, {row}, {col})"
                );
            }
        }
    }
}

#[test]
#[should_panic(expected = "outside")]
fn a_column_past_the_edge_does_not_alias_the_next_row() {
    counting().get(0, 0, 3);
}

#[test]
fn best_where_looks_only_at_allowed_pixels_over_all_rotations() {
    let maps = counting();
    let all = vec![true; 9];
    assert_eq!(maps.best_where(&all), Some((17.0, 1, 2, 2)));
    // Without the last pixel the best is the one before it, still in rotation 1.
    let mut allowed = all.clone();
    allowed[8] = false;
    assert_eq!(maps.best_where(&allowed), Some((16.0, 1, 2, 1)));
    // A single allowed pixel: its better rotation.
    let mut one = vec![false; 9];
    one[4] = true;
    assert_eq!(maps.best_where(&one), Some((13.0, 1, 1, 1)));
    assert_eq!(maps.best_where(&[false; 9]), None);
}

#[test]
fn nan_never_wins_and_all_nan_gives_none() {
    let mut values = vec![f32::NAN; 18];
    values[5] = -3.0;
    values[12] = f32::NAN;
    let maps = QMaps::new(2, 3, values.clone()).unwrap();
    assert_eq!(maps.best_where(&[true; 9]), Some((-3.0, 0, 1, 2)));
    // NaN first in scan order must not block a later value either.
    values[0] = f32::NAN;
    values[17] = 4.0;
    let maps = QMaps::new(2, 3, values).unwrap();
    assert_eq!(maps.best_where(&[true; 9]), Some((4.0, 1, 2, 2)));

    let nan = QMaps::new(2, 3, vec![f32::NAN; 18]).unwrap();
    assert_eq!(nan.best_where(&[true; 9]), None);
    // Minus infinity is a value, not a missing one.
    let low = QMaps::new(1, 3, vec![f32::NEG_INFINITY; 9]).unwrap();
    assert_eq!(
        low.best_where(&[true; 9]),
        Some((f32::NEG_INFINITY, 0, 0, 0))
    );
}

#[test]
fn ties_go_to_the_first_in_rotation_row_column_order() {
    let mut values = vec![0.0; 18];
    values[9 + 1] = 2.0; // rotation 1, (0, 1)
    values[6] = 2.0; // rotation 0, (2, 0)
    values[7] = 2.0; // rotation 0, (2, 1)
    let maps = QMaps::new(2, 3, values).unwrap();
    assert_eq!(maps.best_where(&[true; 9]), Some((2.0, 0, 2, 0)));
    let mut allowed = [true; 9];
    allowed[6] = false;
    assert_eq!(maps.best_where(&allowed), Some((2.0, 0, 2, 1)));
    allowed[7] = false;
    assert_eq!(maps.best_where(&allowed), Some((2.0, 1, 0, 1)));
}

#[test]
#[should_panic(expected = "mask size")]
fn a_mask_of_the_wrong_size_is_refused() {
    counting().best_where(&[true; 8]);
}

#[test]
fn best_where_takes_a_mask_per_rotation() {
    let maps = counting();
    // Rotation 1 closed but for its first pixel; rotation 0 open everywhere.
    let mut allowed = vec![true; 18];
    allowed[10..].iter_mut().for_each(|a| *a = false);
    assert_eq!(maps.best_where(&allowed), Some((9.0, 1, 0, 0)));
    allowed[9] = false;
    assert_eq!(maps.best_where(&allowed), Some((8.0, 0, 2, 2)));
}
