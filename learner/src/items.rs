//! The Q values one sample teaches in an update: its executed action, a grasp's symmetric
//! rotation, and the optional translated and mirrored copies ([`crate::LearningConfig`]).

use qnet::NetInput;
use sim::{Action, Primitive, ROTATIONS};

/// One Q value a sample teaches: an observation, a rotation and a pixel.
#[derive(Clone, Copy)]
pub(crate) struct Item<'a> {
    pub(crate) input: &'a NetInput,
    pub(crate) rotation: u8,
    pub(crate) pixel: (usize, usize),
}

/// What a sample (its input and action) teaches, its own action first: a grasp also at
/// the symmetric rotation k + 8; those again on `translated` (its observation moved by
/// (rows, columns)) at the moved pixel; and a grasp on `mirror` (its observation mirrored)
/// at the mirrored pixel and angle. A reflection takes the jaw angle a to -a, or to pi - a,
/// depending on the axis; the jaws' symmetry makes both the same grasp, so both rotations
/// are taught.
pub(crate) fn taught_items<'a>(
    input: &'a NetInput,
    action: Action,
    mirror: Option<&'a NetInput>,
    translated: Option<(&'a NetInput, (isize, isize))>,
) -> Vec<Item<'a>> {
    let Action {
        primitive,
        rotation: k,
        row,
        col,
    } = action;
    let half = ROTATIONS / 2;
    let own = Item {
        input,
        rotation: k,
        pixel: (row, col),
    };
    let mut items = vec![own];
    if primitive == Primitive::Grasp {
        items.push(Item {
            rotation: (k + half) % ROTATIONS,
            ..own
        });
    }
    if let Some((input, (rows, cols))) = translated {
        let pixel = (
            row.checked_add_signed(rows)
                .expect("a shift keeps the pixel on the map"),
            col.checked_add_signed(cols)
                .expect("a shift keeps the pixel on the map"),
        );
        let moved: Vec<Item> = items
            .iter()
            .map(|item| Item {
                input,
                rotation: item.rotation,
                pixel,
            })
            .collect();
        items.extend(moved);
    }
    if primitive == Primitive::Grasp
        && let Some(mirror) = mirror
    {
        let pixel = (row, mirror.side - 1 - col);
        for rotation in [
            (ROTATIONS - k) % ROTATIONS,
            (ROTATIONS + half - k) % ROTATIONS,
        ] {
            items.push(Item {
                input: mirror,
                rotation,
                pixel,
            });
        }
    }
    items
}
