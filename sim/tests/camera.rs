//! The camera's heightmaps against known geometry, and the measurements built on them.

use sim::measure::{detect_change, most_crowded, occupancy_ratio};
use sim::rapier3d::prelude::{Pose, Rotation, Vector};
use sim::workspace::{CENTRE, SIDE, X_MAX, X_MIN, Y_MIN, inside_by};
use sim::{ANY_OBJECT, Camera, Heightmaps, ShapeKind, SimConfig, Tabletop};

fn render(tabletop: &Tabletop) -> Heightmaps {
    Camera::new(tabletop.grid()).render(tabletop)
}

/// Pixels owned by `id`, as (min row, max row, min col, max col, count).
fn footprint(maps: &Heightmaps, id: u8) -> (usize, usize, usize, usize, usize) {
    let mut b = (usize::MAX, 0, usize::MAX, 0, 0);
    for (i, _) in maps.ids.iter().enumerate().filter(|(_, v)| **v == id) {
        let (r, c) = (i / maps.side(), i % maps.side());
        b = (b.0.min(r), b.1.max(r), b.2.min(c), b.3.max(c), b.4 + 1);
    }
    b
}

#[test]
fn a_known_box_has_its_footprint_within_a_pixel_and_its_height_within_a_millimetre() {
    for pixel_size in [0.002f32, 0.004] {
        let config = SimConfig::with_pixel_size(pixel_size);
        let mut tabletop = Tabletop::new(&config).unwrap();
        // A flat bar (10 x 5 x 2.5 cm) lying with its long side along x, at a known place.
        let (x, y) = (-0.55, 0.031);
        let lying = Rotation::from_rotation_y(std::f32::consts::FRAC_PI_2);
        let pose = Pose::from_parts(Vector::new(x, y, 0.0125), lying);
        tabletop
            .add_object(7, ShapeKind::Bar, [1, 2, 3], pose)
            .unwrap();
        let maps = render(&tabletop);

        let (r0, r1, c0, c1, count) = footprint(&maps, 7);
        let edge = |v: f32, lo: f32| (v - lo) / pixel_size;
        let want = (
            edge(y - 0.025, Y_MIN),
            edge(y + 0.025, Y_MIN),
            edge(x - 0.05, X_MIN),
            edge(x + 0.05, X_MIN),
        );
        assert!(
            (r0 as f32 - want.0).abs() <= 1.0,
            "{pixel_size}: top row {r0} vs {}",
            want.0
        );
        assert!(
            (r1 as f32 + 1.0 - want.1).abs() <= 1.0,
            "{pixel_size}: bottom row {r1}"
        );
        assert!(
            (c0 as f32 - want.2).abs() <= 1.0,
            "{pixel_size}: left col {c0}"
        );
        assert!(
            (c1 as f32 + 1.0 - want.3).abs() <= 1.0,
            "{pixel_size}: right col {c1}"
        );
        let area = 0.10 * 0.05 / (pixel_size * pixel_size);
        assert!(
            (count as f32 - area).abs() / area < 0.06,
            "{count} pixels vs {area}"
        );

        for i in (0..maps.ids.len()).filter(|&i| maps.ids[i] == 7) {
            assert!(
                (maps.height[i] - 0.025).abs() < 0.001,
                "height {}",
                maps.height[i]
            );
            assert_eq!(maps.colour[i], [1, 2, 3]);
        }
        let outside = (0..maps.ids.len()).filter(|&i| maps.ids[i] == 0);
        assert!(outside.clone().all(|i| maps.height[i] == 0.0));
        assert!(outside.count() > 0);
    }
}

#[test]
fn the_highest_surface_wins_and_sloped_faces_are_exact() {
    let mut tabletop = Tabletop::new(&SimConfig::default()).unwrap();
    // A cube on the table and a second cube resting on it, offset by 2 cm in x.
    let (x, y) = (CENTRE[0], CENTRE[1]);
    tabletop
        .add_object(
            1,
            ShapeKind::Cube,
            [10, 10, 10],
            Pose::from_translation(Vector::new(x, y, 0.025)),
        )
        .unwrap();
    tabletop
        .add_object(
            2,
            ShapeKind::Cube,
            [20, 20, 20],
            Pose::from_translation(Vector::new(x + 0.02, y, 0.075)),
        )
        .unwrap();
    // A roof on its base: body -x down, so rotate body x onto world z.
    let upright = Rotation::from_rotation_y(-std::f32::consts::FRAC_PI_2);
    let roof_at = Vector::new(x, y + 0.12, 0.0245);
    tabletop
        .add_object(
            3,
            ShapeKind::Roof,
            [30, 30, 30],
            Pose::from_parts(roof_at, upright),
        )
        .unwrap();
    let maps = render(&tabletop);
    let grid = tabletop.grid();

    let at = |dx: f32, dy: f32| {
        let (r, c) = grid.pixel_of(x + dx, y + dy).unwrap();
        let i = maps.index(r, c);
        (maps.ids[i], maps.height[i])
    };
    let (id, h) = at(0.03, 0.0);
    assert_eq!(id, 2);
    assert!((h - 0.1).abs() < 1e-3, "{h}");
    let (id, h) = at(-0.02, 0.0);
    assert_eq!(id, 1);
    assert!((h - 0.05).abs() < 1e-3, "{h}");
    assert_eq!(maps.visible_ids(), vec![1, 2, 3]);

    // The roof's ridge runs along y (its body y stays y), slopes at 45 degrees down in x:
    // height = 0.049 - |dx| for |dx| up to the 2.5 mm walls.
    for dx in [0.0f32, 0.01, -0.02, 0.03] {
        let (r, c) = grid.pixel_of(x + dx, y + 0.12).unwrap();
        let [px, _] = grid.pixel_centre(r, c);
        let want = 0.049 - (px - x).abs();
        let (id, h) = at(dx, 0.12);
        assert_eq!(id, 3);
        assert!((h - want).abs() < 1e-3, "dx {dx}: {h} vs {want}");
    }
}

#[test]
fn the_goal_mask_is_the_goal_pixels_of_the_id_map() {
    let (tabletop, _) = Tabletop::random(&SimConfig::with_pixel_size(0.004), 6, 4).unwrap();
    let maps = render(&tabletop);
    for id in maps.visible_ids() {
        let mask = maps.goal_mask(id);
        assert!(mask.iter().any(|&m| m));
        assert!(mask.iter().zip(&maps.ids).all(|(&m, &i)| m == (i == id)));
    }
    assert!(
        maps.goal_mask(ANY_OBJECT)
            .iter()
            .zip(&maps.ids)
            .all(|(&m, &i)| m == (i != 0)),
        "the goal-agnostic mask is every object and never the table"
    );
}

/// A goal cube with `neighbours` cubes packed around it (5.5 cm apart, in a ring).
fn surrounded(neighbours: usize) -> Tabletop {
    let mut tabletop = Tabletop::new(&SimConfig::default()).unwrap();
    let (x, y) = (CENTRE[0], CENTRE[1]);
    tabletop
        .add_object(
            1,
            ShapeKind::Cube,
            [1, 1, 1],
            Pose::from_translation(Vector::new(x, y, 0.025)),
        )
        .unwrap();
    let offsets = [(0.055, 0.0), (-0.055, 0.0), (0.0, 0.055), (0.0, -0.055)];
    for (k, (dx, dy)) in offsets.iter().take(neighbours).enumerate() {
        let at = Vector::new(x + dx, y + dy, 0.025);
        tabletop
            .add_object(
                k as u8 + 2,
                ShapeKind::Cube,
                [2, 2, 2],
                Pose::from_translation(at),
            )
            .unwrap();
    }
    tabletop
}

#[test]
fn occupancy_rises_with_neighbours_and_is_scaled_to_the_pixel_size() {
    let ratios: Vec<f32> = (0..=4)
        .map(|n| occupancy_ratio(&render(&surrounded(n)), 1))
        .collect();
    assert_eq!(ratios[0], 0.0);
    assert!(ratios.windows(2).all(|w| w[1] > w[0]), "{ratios:?}");
    // With four neighbours 5 mm from the goal's faces, a 2 cm ring is mostly occupied.
    assert!(ratios[4] > 0.5, "{ratios:?}");

    // The same scene at 4 mm gives nearly the same ratio: the ring width scales.
    let mut coarse = surrounded(4);
    let at_4mm = Camera::new(sim::PixelGrid::new(0.004).unwrap()).render(&coarse);
    assert!((occupancy_ratio(&at_4mm, 1) - ratios[4]).abs() < 0.08);
    coarse.remove_object(1);
    assert_eq!(
        occupancy_ratio(&render(&coarse), 1),
        1.0,
        "a hidden goal is fully surrounded"
    );
}

#[test]
fn the_most_crowded_object_is_the_one_with_neighbours_all_round() {
    // The centre cube has four neighbours; each neighbour has one (the centre) within its
    // ring.
    let crowded = render(&surrounded(4));
    assert_eq!(most_crowded(&crowded, &crowded.visible_ids()), Some(1));
    // Whatever the scene, no object seen has a more occupied ring than the one chosen.
    let pair = render(&surrounded(1));
    let best = most_crowded(&pair, &pair.visible_ids()).unwrap();
    let others = pair.visible_ids();
    assert!(
        others
            .iter()
            .all(|&id| occupancy_ratio(&pair, id) <= occupancy_ratio(&pair, best))
    );
    let mut empty = surrounded(0);
    empty.remove_object(1);
    assert_eq!(most_crowded(&render(&empty), &[]), None);
}

#[test]
fn change_is_detected_when_the_goals_surroundings_clear() {
    let crowded = surrounded(4);
    let before = render(&crowded);
    let mut cleared = surrounded(4);
    cleared.remove_object(2);
    cleared.remove_object(3);
    let after = render(&cleared);
    let change = detect_change(&before, &after, 1);
    assert!(change.detected, "{change:?}");
    assert!(change.changed_pixels > change.changed_pixels_needed);
    assert!(change.occupancy_before - change.occupancy_after > 0.1);

    let unchanged = detect_change(&before, &before, 1);
    assert!(!unchanged.detected);
    assert_eq!(unchanged.changed_pixels, 0);

    // Far-away changes are not changes around the goal.
    let mut far = surrounded(4);
    far.add_object(
        9,
        ShapeKind::Cube,
        [3, 3, 3],
        Pose::from_translation(Vector::new(-0.35, 0.15, 0.025)),
    )
    .unwrap();
    let with_far = render(&far);
    let far_change = detect_change(&with_far, &before, 1);
    assert_eq!(far_change.changed_pixels, 0);
    assert!(!far_change.detected);

    // The pixel threshold scales with the pixel area: 50 at 2 mm, about 12 at 4 mm.
    assert_eq!(change.changed_pixels_needed, 50);
    let grid = sim::PixelGrid::new(0.004).unwrap();
    let coarse = detect_change(
        &Camera::new(grid).render(&crowded),
        &Camera::new(grid).render(&cleared),
        1,
    );
    assert_eq!(coarse.changed_pixels_needed, 13);
    assert!(coarse.detected, "{coarse:?}");
}

#[test]
fn heightmaps_round_trip_through_serde_and_refuse_a_wrong_size() {
    // 0.056 m pixels: an 8 x 8 grid keeps the text small.
    let config = SimConfig::with_pixel_size(0.056);
    let (tabletop, _) = Tabletop::random(&config, 3, 5).unwrap();
    let maps = render(&tabletop);
    let text = toml::to_string(&maps).unwrap();
    let back: Heightmaps = toml::from_str(&text).unwrap();
    assert_eq!(back, maps);

    let mut short: toml::Table = toml::from_str(&text).unwrap();
    short["ids"].as_array_mut().unwrap().pop();
    let error = toml::from_str::<Heightmaps>(&short.to_string()).unwrap_err();
    assert!(
        error.to_string().contains("63 id pixels on a grid of 64"),
        "{error}"
    );
}

#[test]
fn shape_bounds_hold_every_part_and_match_the_catalogue_sizes() {
    let (lo, hi) = ShapeKind::Cube.bounds();
    assert!((hi - lo - Vector::splat(0.05)).abs().max_element() < 1e-4);
    let (lo, hi) = ShapeKind::TallBlock.bounds();
    let size = hi - lo;
    assert!((size.max_element() - 0.10).abs() < 1e-3, "{size:?}");
    for kind in ShapeKind::ALL {
        let (lo, hi) = kind.bounds();
        for part in kind.parts() {
            for v in &part.vertices {
                assert!(v.cmpge(lo).all() && v.cmple(hi).all(), "{kind:?}");
            }
        }
    }
}

#[test]
fn a_point_lies_inside_the_workspace_by_its_distance_to_the_nearest_edge() {
    assert!((inside_by(CENTRE[0], CENTRE[1]) - SIDE / 2.0).abs() < 1e-6);
    assert!((inside_by(X_MIN + 0.03, CENTRE[1] + 0.1) - 0.03).abs() < 1e-6);
    assert!((inside_by(X_MAX + 0.01, CENTRE[1]) + 0.01).abs() < 1e-6);
}
