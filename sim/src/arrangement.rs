//! Arrangement files: designed scenes, in the original test-case format or our own TOML.
//!
//! The original format has one line per object slot, `<mesh.obj> R G B x y z rx ry rz`: RGB
//! in [0, 1], position in metres in the original world frame, Euler angles in radians applied
//! about x, then y, then z of the moving frame (V-REP's convention). The line index is the
//! slot; object ids are slot + 1, so the paper's goal slot g is object g + 1. Objects parked
//! off the workspace are left out.
//!
//! The grasping-invisible test cases (Yang et al. 2020) use `<name> <mesh.obj> x y z rx ry rz`
//! in the same frame: every object is named `block` but the goal, which is named by its
//! colour. Those files give no RGB, so each object takes the slot colour our random scenes
//! give the k-th object ([`SLOT_COLOURS`]); the name only marks the goal.
//!
//! Our TOML format also names the goal:
//!
//! ```toml
//! name = "challenging-00"
//! goal = 5
//!
//! [[objects]]
//! id = 5
//! shape = "cube"
//! colour = [89, 161, 79]
//! position = [-0.6398, 0.1028, 0.0260]
//! euler_xyz = [-1.5746, -1.0274, 3.1371]
//! ```

use std::path::{Path, PathBuf};

use rand::{Rng, RngExt};
use rapier3d::glamx;
use rapier3d::prelude::*;
use serde::{Deserialize, Serialize};

use crate::catalogue::{SLOT_COLOURS, ShapeKind};
use crate::error::ArrangementError;
use crate::tabletop::ObjectId;
use crate::workspace;

/// Options for reading the original format.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OriginalOptions {
    /// Add 0.1 m to y, as the authors' loader does (the VPG loader does not).
    pub y_offset: bool,
}

/// The y shift of the authors' loader.
const AUTHORS_Y_OFFSET: f32 = 0.1;
/// Objects farther than this below or above the table are parked, not part of the scene.
const PARKED_Z: f32 = 1.0;
/// What the grasping-invisible format calls every object but the goal.
const DISTRACTOR_NAME: &str = "block";
/// The numbers of an original line, in order; the grasping-invisible format has the last six.
const NUMBER_FIELDS: [&str; 9] = ["red", "green", "blue", "x", "y", "z", "rx", "ry", "rz"];

/// A designed scene.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Arrangement {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// The goal object, if the file names one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub goal: Option<ObjectId>,
    pub objects: Vec<PlacedObject>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlacedObject {
    pub id: ObjectId,
    pub shape: ShapeKind,
    pub colour: [u8; 3],
    /// Centre of the shape's bounding box, metres, original world frame.
    pub position: [f32; 3],
    /// Radians about x, then y, then z of the moving frame.
    #[serde(default)]
    pub euler_xyz: [f32; 3],
}

impl PlacedObject {
    /// An object at `pose`, its rotation written as the file's Euler angles.
    pub fn at(id: ObjectId, shape: ShapeKind, colour: [u8; 3], pose: Pose) -> Self {
        let (x, y, z) = pose.rotation.to_euler(glamx::EulerRot::XYZ);
        Self {
            id,
            shape,
            colour,
            position: pose.translation.to_array(),
            euler_xyz: [x, y, z],
        }
    }

    pub fn pose(&self) -> Pose {
        let [a, b, c] = self.euler_xyz;
        let rotation = Rotation::from_rotation_x(a)
            * Rotation::from_rotation_y(b)
            * Rotation::from_rotation_z(c);
        Pose::from_parts(Vector::from_array(self.position), rotation)
    }
}

impl Arrangement {
    /// A copy with every object shifted by up to `metres` in x and y and turned by up to
    /// `radians` about the vertical, uniformly: the simulator is deterministic, so this
    /// stands in for the run-to-run noise of a real scene.
    pub fn jittered(&self, metres: f32, radians: f32, rng: &mut impl Rng) -> Self {
        let mut jittered = self.clone();
        for object in &mut jittered.objects {
            let mut shift = |range: f32| rng.random_range(-range..=range);
            let pose = object.pose();
            let moved = pose.translation + Vector::new(shift(metres), shift(metres), 0.0);
            // About the world's vertical: the file's last Euler angle turns the object about
            // its own z, which lies flat for most arranged objects and would tilt them.
            let turned = Rotation::from_rotation_z(shift(radians)) * pose.rotation;
            *object = PlacedObject::at(
                object.id,
                object.shape,
                object.colour,
                Pose::from_parts(moved, turned),
            );
        }
        jittered
    }

    /// Reads a file: `.toml` as our format, anything else as the original format.
    pub fn read(path: &Path, options: &OriginalOptions) -> Result<Self, ArrangementError> {
        let text = std::fs::read_to_string(path).map_err(|source| ArrangementError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        if path.extension().is_some_and(|e| e == "toml") {
            Self::parse_toml(&text, path)
        } else {
            Self::parse_original(&text, path, options)
        }
    }

    /// Parses the original test-case formats (see the module's docs); `path` names the
    /// source in errors.
    pub fn parse_original(
        text: &str,
        path: &Path,
        options: &OriginalOptions,
    ) -> Result<Self, ArrangementError> {
        let at = |line: usize, message: String| ArrangementError::Line {
            path: path.to_path_buf(),
            line,
            message,
        };
        let mut objects = Vec::new();
        // The named goal's line, name and id.
        let mut goal: Option<(usize, &str, ObjectId)> = None;
        for (index, content) in text.lines().enumerate() {
            let line = index + 1;
            let fields: Vec<&str> = content.split_whitespace().collect();
            let id = ObjectId::try_from(line)
                .map_err(|_| at(line, "more than 255 object slots".to_string()))?;
            let (name, mesh, numbers) = match fields.len() {
                10 => (None, fields[0], &fields[1..]),
                8 => (Some(fields[0]), fields[1], &fields[2..]),
                n => {
                    return Err(at(
                        line,
                        format!(
                            "expected `<mesh.obj> R G B x y z rx ry rz` (10 fields) or `<name> <mesh.obj> x y z rx ry rz` (8), found {n} fields"
                        ),
                    ));
                }
            };
            let shape = ShapeKind::from_mesh_name(mesh).ok_or_else(|| {
                let known: Vec<&str> = ShapeKind::ALL.iter().map(|k| k.mesh_name()).collect();
                at(
                    line,
                    format!(
                        "mesh `{mesh}` is not in the catalogue (known: {})",
                        known.join(", ")
                    ),
                )
            })?;
            let numbers = parse_numbers(numbers).map_err(|message| at(line, message))?;
            let (colour, pose) = match numbers.len() {
                9 => {
                    let rgb = [numbers[0], numbers[1], numbers[2]];
                    if let Some(i) = rgb.iter().position(|c| !(0.0..=1.0).contains(c)) {
                        return Err(at(
                            line,
                            format!(
                                "colour field `{}` = {} is outside [0, 1]",
                                NUMBER_FIELDS[i], rgb[i]
                            ),
                        ));
                    }
                    (rgb.map(|c| (c * 255.0).round() as u8), &numbers[3..])
                }
                _ => (SLOT_COLOURS[index % SLOT_COLOURS.len()], &numbers[..]),
            };
            let mut position = [pose[0], pose[1], pose[2]];
            if options.y_offset {
                position[1] += AUTHORS_Y_OFFSET;
            }
            let on_table =
                position[2].abs() <= PARKED_Z && workspace::contains(position[0], position[1]);
            if let Some(name) = name.filter(|&name| name != DISTRACTOR_NAME) {
                if let Some((first, first_name, _)) = goal {
                    return Err(at(
                        line,
                        format!(
                            "`{name}` is a second goal (line {first} names `{first_name}`; every other object is `{DISTRACTOR_NAME}`)"
                        ),
                    ));
                }
                if !on_table {
                    return Err(at(
                        line,
                        format!("the goal `{name}` lies off the workspace"),
                    ));
                }
                goal = Some((line, name, id));
            }
            if !on_table {
                continue;
            }
            objects.push(PlacedObject {
                id,
                shape,
                colour,
                position,
                euler_xyz: [pose[3], pose[4], pose[5]],
            });
        }
        Ok(Self {
            name: path.file_stem().map(|s| s.to_string_lossy().into_owned()),
            goal: goal.map(|(_, _, id)| id),
            objects,
        })
    }

    /// Parses our TOML format; `path` names the source in errors.
    pub fn parse_toml(text: &str, path: &Path) -> Result<Self, ArrangementError> {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct File {
            name: Option<String>,
            goal: Option<toml::Spanned<ObjectId>>,
            objects: Vec<toml::Spanned<PlacedObject>>,
        }
        let file: File = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| line_of(text, s.start));
            match line {
                Some(line) => ArrangementError::Line {
                    path: path.to_path_buf(),
                    line,
                    message: e.message().to_string(),
                },
                None => ArrangementError::File {
                    path: path.to_path_buf(),
                    message: e.message().to_string(),
                },
            }
        })?;
        let at = |offset: usize, message: String| ArrangementError::Line {
            path: PathBuf::from(path),
            line: line_of(text, offset),
            message,
        };
        let mut objects: Vec<PlacedObject> = Vec::with_capacity(file.objects.len());
        for spanned in file.objects {
            let start = spanned.span().start;
            let object = spanned.into_inner();
            if object.id == 0 {
                return Err(at(
                    start,
                    "object id 0 is the table; ids are 1..=255".into(),
                ));
            }
            if objects.iter().any(|o| o.id == object.id) {
                return Err(at(start, format!("object id {} appears twice", object.id)));
            }
            if object
                .position
                .iter()
                .chain(&object.euler_xyz)
                .any(|v| !v.is_finite())
            {
                return Err(at(
                    start,
                    format!("object {} has a non-finite pose", object.id),
                ));
            }
            objects.push(object);
        }
        let goal = match file.goal {
            Some(goal) if !objects.iter().any(|o| o.id == *goal.get_ref()) => {
                return Err(at(
                    goal.span().start,
                    format!("goal {} is not one of the objects", goal.get_ref()),
                ));
            }
            goal => goal.map(|g| g.into_inner()),
        };
        Ok(Self {
            name: file.name,
            goal,
            objects,
        })
    }

    /// The arrangement in our TOML format.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("arrangements always serialise")
    }
}

/// A line's numeric fields (the last `fields.len()` of [`NUMBER_FIELDS`]), or what is wrong.
fn parse_numbers(fields: &[&str]) -> Result<Vec<f32>, String> {
    let names = &NUMBER_FIELDS[NUMBER_FIELDS.len() - fields.len()..];
    fields
        .iter()
        .zip(names)
        .map(|(field, name)| {
            field
                .parse::<f32>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("field `{name}` is not a finite number: `{field}`"))
        })
        .collect()
}

/// The 1-based line holding a byte offset.
fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}
