//! Pushes and grasps whose jaws would come down on an object. A push lowers its closed jaws
//! at the start to just below the highest point of a 2 cm window there, but the jaws are
//! wider than that window (41 mm along the push at the knuckles): beside it they can come
//! down on an object, which the simulator, driving them on down, squeezes into the table
//! until the fingers give way and throw it, and its neighbours, at 1-2 m/s. A real arm would
//! stop on the contact. A grasp lowers its open jaws (pads 100 mm apart) until the tool point
//! is 4 cm below the surface at its pixel, the pads' ends 15.5 mm above it: a pad can come
//! down on a neighbour's top, which holds the jaws up, so that they close above the goal and
//! pick nothing. Judged from the heightmap, as a robot could judge it: an action is closed
//! where a pixel under one of the jaws' parts ([`sim::jaws_parts`], widened by a margin for
//! what the pixels miss of an object's sloping sides) stands higher than that part's lower
//! face, the pads' ends being where the primitive lowers them
//! ([`sim::push_pad_ends_height`], [`sim::grasp_pad_ends_height`]). A pixel's height is the
//! surface at its centre, so a corner can reach under the jaws in a pixel whose centre is on
//! the table; the goal, whose loss ends the run, is also judged on the scene rendered finer
//! ([`pushes_landing_clear_of`]).

use std::borrow::Cow;

use sim::{
    Heightmaps, Jaws, JawsPart, ObjectId, ROTATIONS, grasp_pad_ends_height, jaws_parts,
    push_pad_ends_height,
};

/// A surface within this of a part's lower face is not pressed: bare table under a push's
/// pads' ends, which come down onto it.
const PRESS_TOLERANCE: f32 = 0.001;

/// For each rotation and start pixel, laid out `[rotation][row][col]` as
/// [`QMaps`](crate::QMaps): whether a push from there lowers the closed jaws, widened by
/// `margin` metres on every side, onto nothing higher than their parts' lower faces.
pub fn pushes_landing_clear(obs: &Heightmaps, margin: f32) -> Vec<bool> {
    landing_clear(
        obs,
        obs,
        None,
        Jaws::Closed,
        push_pad_ends_height,
        margin,
        |_| true,
    )
}

/// For each rotation and start pixel, laid out as [`pushes_landing_clear`]: whether a push
/// from there lowers the closed jaws, widened by `margin` metres on every side, clear of
/// `goal` as `view` sees it: the scene rendered an odd number of times finer than `obs`
/// on the same workspace ([`PolicyConfig::landing_view`](crate::PolicyConfig::landing_view)).
pub fn pushes_landing_clear_of(
    obs: &Heightmaps,
    view: &Heightmaps,
    goal: ObjectId,
    margin: f32,
) -> Vec<bool> {
    pushes_clear_of_where(obs, view, goal, margin, |_| true)
}

/// [`pushes_landing_clear_of`] judged only at the pixels `starts` names (at every rotation),
/// open everywhere else: the few starts a retreat weighs
/// ([`push_start_clear_of_goal`](crate::push_start_clear_of_goal)), without the whole map.
pub fn pushes_landing_clear_of_at(
    obs: &Heightmaps,
    view: &Heightmaps,
    goal: ObjectId,
    margin: f32,
    starts: &[[usize; 2]],
) -> Vec<bool> {
    let side = obs.side();
    pushes_clear_of_where(obs, view, goal, margin, |i| {
        starts.contains(&[i / side, i % side])
    })
}

/// Pushes landing clear of `goal` on `view`, judged at the pixels `judged` holds.
fn pushes_clear_of_where(
    obs: &Heightmaps,
    view: &Heightmaps,
    goal: ObjectId,
    margin: f32,
    judged: impl Fn(usize) -> bool,
) -> Vec<bool> {
    landing_clear(
        obs,
        view,
        Some(goal),
        Jaws::Closed,
        push_pad_ends_height,
        margin,
        judged,
    )
}

/// For each rotation and pixel, laid out as [`pushes_landing_clear`]: whether a grasp there
/// lowers the open jaws, widened by `margin` metres on every side, onto nothing higher than
/// their parts' lower faces. Judged only at the pixels `within` holds (one `side * side`
/// mask, the grasp region: a grasp goes nowhere else); open at the others.
pub fn grasps_landing_clear(obs: &Heightmaps, margin: f32, within: &[bool]) -> Vec<bool> {
    landing_clear(
        obs,
        obs,
        None,
        Jaws::Open,
        grasp_pad_ends_height,
        margin,
        |i| within[i],
    )
}

/// Whether the jaws at `jaws`, their pads' ends lowered to `pad_ends(obs, row, col)` over
/// each pixel `judged` holds, come down clear of `view`'s surfaces (`only` that object's,
/// where given), per rotation; open where it is not judged. On a finer view, a start is
/// judged on the view's pixels only where the coarse test on each observation pixel's
/// highest view pixel does not already find it clear.
fn landing_clear(
    obs: &Heightmaps,
    view: &Heightmaps,
    only: Option<ObjectId>,
    jaws: Jaws,
    pad_ends: fn(&Heightmaps, usize, usize) -> f32,
    margin: f32,
    judged: impl Fn(usize) -> bool,
) -> Vec<bool> {
    let side = obs.side();
    let factor = view.side() / side;
    assert!(
        view.side() == side * factor && !factor.is_multiple_of(2),
        "a landing view {} pixels a side over observations of {side}",
        view.side()
    );
    let parts = jaws_parts(jaws);
    let (pixel, fine_pixel) = (obs.grid.pixel_size(), view.grid.pixel_size());
    // A fine pixel under the jaws lies in an observation pixel whose centre is at most half
    // its diagonal farther out: the coarse test, so widened, misses nothing the fine one finds.
    let (coarse, fine) = if factor == 1 {
        (footprints(&parts, pixel, margin + 0.5 * pixel), Vec::new())
    } else {
        let fine_widening = margin + 0.5 * fine_pixel;
        let coarse_widening = fine_widening + std::f32::consts::FRAC_1_SQRT_2 * pixel;
        (
            footprints(&parts, pixel, coarse_widening),
            footprints(&parts, fine_pixel, fine_widening),
        )
    };
    let heights: Cow<[f32]> = match only {
        None => Cow::Borrowed(&view.height),
        Some(id) => (view.height.iter().zip(&view.ids))
            .map(|(&h, &of)| if of == id { h } else { 0.0 })
            .collect(),
    };
    let highest = highest_per_pixel(&heights, view.side(), side, factor);
    let pad_ends: Vec<Option<f32>> = (0..side * side)
        .map(|i| judged(i).then(|| pad_ends(obs, i / side, i % side)))
        .collect();
    let mut clear = Vec::with_capacity(ROTATIONS as usize * side * side);
    for (rotation, footprint) in coarse.iter().enumerate() {
        clear.extend(pad_ends.iter().enumerate().map(|(start, pad_ends)| {
            let Some(pad_ends) = *pad_ends else {
                return true;
            };
            let (row, col) = (start / side, start % side);
            !presses(&highest, side, [row, col], footprint, pad_ends)
                || (factor > 1 && {
                    let centre = [row * factor + factor / 2, col * factor + factor / 2];
                    !presses(&heights, view.side(), centre, &fine[rotation], pad_ends)
                })
        }));
    }
    clear
}

/// Whether any pixel of `heights` (`side x side`) under `footprint`, placed at pixel
/// `[row, col]`, stands higher than its part's lower face, the pads' ends at `pad_ends`.
fn presses(
    heights: &[f32],
    side: usize,
    [row, col]: [usize; 2],
    footprint: &[UnderJaws],
    pad_ends: f32,
) -> bool {
    footprint.iter().any(|under| {
        let (r, c) = (
            row as isize + under.offset[1],
            col as isize + under.offset[0],
        );
        let inside = |a: isize| (0..side as isize).contains(&a);
        inside(r)
            && inside(c)
            && heights[r as usize * side + c as usize]
                > pad_ends + under.above_pad_ends + PRESS_TOLERANCE
    })
}

/// For each observation pixel (`side x side`), the highest of the `factor x factor`
/// pixels of `heights` (`fine_side x fine_side`) it holds: `heights` itself at a factor of 1.
fn highest_per_pixel(
    heights: &[f32],
    fine_side: usize,
    side: usize,
    factor: usize,
) -> Cow<'_, [f32]> {
    if factor == 1 {
        return Cow::Borrowed(heights);
    }
    let mut highest = vec![0.0f32; side * side];
    for (i, &h) in heights.iter().enumerate() {
        let (r, c) = (i / fine_side / factor, i % fine_side / factor);
        let top = &mut highest[r * side + c];
        *top = top.max(h);
    }
    Cow::Owned(highest)
}

/// A pixel under the jaws, relative to the action's pixel: its (column, row)
/// offset, and the lowest lower face above it of the parts it lies under, above the pads'
/// ends.
struct UnderJaws {
    offset: [isize; 2],
    above_pad_ends: f32,
}

/// For each rotation, the pixels (of `pixel_size` metres) whose centres lie under one of
/// `parts` widened by `widen` metres (the margin and half a pixel: a pixel counts where any
/// of it is).
fn footprints(parts: &[JawsPart], pixel_size: f32, widen: f32) -> Vec<Vec<UnderJaws>> {
    let far = |[a, b]: [f32; 2]| a.abs().max(b.abs()) + widen;
    let reach = parts
        .iter()
        .map(|p| far(p.along).hypot(far(p.across)))
        .fold(0.0, f32::max);
    let reach = (reach / pixel_size).ceil() as isize;
    let covers = |[from, to]: [f32; 2], at: f32| (from - widen..=to + widen).contains(&at);
    (0..ROTATIONS)
        .map(|rotation| {
            let angle = sim::rotation_angle(rotation);
            let (cos, sin) = (angle.cos(), angle.sin());
            let mut under = Vec::new();
            for dr in -reach..=reach {
                for dc in -reach..=reach {
                    let (x, y) = (dc as f32 * pixel_size, dr as f32 * pixel_size);
                    let (along, across) = (x * cos + y * sin, y * cos - x * sin);
                    let lowest = parts
                        .iter()
                        .filter(|p| covers(p.along, along) && covers(p.across, across))
                        .map(|p| p.above_pad_ends)
                        .reduce(f32::min);
                    if let Some(above_pad_ends) = lowest {
                        under.push(UnderJaws {
                            offset: [dc, dr],
                            above_pad_ends,
                        });
                    }
                }
            }
            under
        })
        .collect()
}
