//! Arrangement files: the original test cases load as their lines say, rest as designed and
//! stay put when physics takes over; our TOML files round-trip and match the originals; the
//! validation cases are held out from the challenging ones; and malformed files are reported
//! with their path and line.
//!
//! The original files are read from `PUSHGRASP_TEST_CASES`, else from
//! `../shared/reference/test-cases/` beside the checkout; tests that need them say they are
//! skipping when neither is there.

use std::f32::consts::FRAC_PI_2;
use std::path::{Path, PathBuf};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sim::rapier3d::parry::query;
use sim::rapier3d::prelude::*;
use sim::{
    Arrangement, ArrangementError, ObjectId, OriginalOptions, PlacedObject, ShapeKind, SimConfig,
    Tabletop,
};

/// The paper's test cases: `test-10-obj-*` are the challenging cases, `novel-obj-*` use
/// meshes outside our catalogue.
const PAPER_DIR: &str = "Efficient_goal-oriented_push-grasping_synergy";
/// The VPG test cases, all in the block catalogue.
const VPG_DIR: &str = "visual-pushing-grasping";
/// The grasping-invisible test cases, which name their goal (`<name> <mesh.obj> x y z rx ry rz`).
const GRASPING_INVISIBLE_DIR: &str = "grasping-invisible/preset";
/// The paper's goal slot for challenging cases 00..09.
const CHALLENGING_GOAL_SLOTS: [ObjectId; 10] = [4, 7, 8, 7, 7, 3, 1, 7, 5, 9];

/// Workspace bounds and the parking depth, restated here so the loader is checked against
/// an independent reading of the files.
const X_RANGE: (f32, f32) = (-0.724, -0.276);
const Y_RANGE: (f32, f32) = (-0.224, 0.224);
const PARKED_Z: f32 = 1.0;
/// The authors' loader shifts y by this much.
const Y_OFFSET: f32 = 0.1;

/// How close a designed object must be to what holds it up, and how far two designed
/// objects may overlap (m).
const REST_TOLERANCE: f32 = 0.003;
/// How far settling may move a designed object (m).
const SETTLE_TOLERANCE: f32 = 0.01;
/// Physics run on after `settle` reports rest (s): designed scenes come to rest within a few
/// dozen steps, too soon to tell a stable stack from one slowly tipping over.
const AFTER_SETTLE_S: f32 = 1.0;

// ---------------------------------------------------------------------------------------
// Where the files are.

/// The original test-case directory, or `None` (with a note on stderr) when it is missing.
fn test_cases_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("PUSHGRASP_TEST_CASES")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../shared/reference/test-cases"
            ))
        });
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("skipping: {} not found", dir.display());
        None
    }
}

/// The files in `dir` whose names start with `prefix`, sorted by name.
fn files_starting_with(dir: &Path, prefix: &str) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("cannot list {}: {e}", dir.display()))
        .map(|entry| entry.expect("directory entry").path())
        .filter(|path| {
            path.file_name()
                .is_some_and(|name| name.to_string_lossy().starts_with(prefix))
        })
        .collect();
    files.sort();
    files
}

/// Every original file in our catalogue: the paper's challenging cases and all of VPG's.
fn original_files(cases: &Path) -> Vec<PathBuf> {
    let mut files = files_starting_with(&cases.join(PAPER_DIR), "test-10-obj-");
    files.extend(files_starting_with(&cases.join(VPG_DIR), ""));
    assert_eq!(files.len(), 21, "10 paper and 11 VPG test cases");
    files
}

fn challenging_files() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/arrangements");
    files_starting_with(&dir, "challenging-")
}

/// `configs/validation/`: grasping-invisible coordination cases, converted.
fn validation_files() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/validation");
    files_starting_with(&dir, "coordination-")
}

fn load(path: &Path, options: &OriginalOptions) -> Arrangement {
    Arrangement::read(path, options).unwrap_or_else(|e| panic!("{e}"))
}

/// The scenes designed to rest as they are: the original files when they are here, else our
/// TOML copies of the paper's ten; and the validation cases.
fn designed_scenes() -> Vec<(PathBuf, Arrangement)> {
    let mut files = match test_cases_dir() {
        Some(cases) => original_files(&cases),
        None => {
            eprintln!("using configs/arrangements/ instead of the original files");
            challenging_files()
        }
    };
    files.extend(validation_files());
    files
        .into_iter()
        .map(|path| {
            let arrangement = load(&path, &OriginalOptions::default());
            (path, arrangement)
        })
        .collect()
}

// ---------------------------------------------------------------------------------------
// Loading the original format.

/// The objects a file's lines describe, read here without the library's parser: line k
/// (from 0) is object k + 1, kept when it lies over the workspace and is not parked.
fn objects_in_lines(text: &str) -> Vec<PlacedObject> {
    text.lines()
        .enumerate()
        .filter_map(|(index, line)| {
            let fields: Vec<&str> = line.split_whitespace().collect();
            assert_eq!(fields.len(), 10, "line {}: {line}", index + 1);
            let number = |i: usize| -> f32 { fields[i].parse().expect("a number") };
            let [x, y, z] = [number(4), number(5), number(6)];
            let inside = (X_RANGE.0..=X_RANGE.1).contains(&x)
                && (Y_RANGE.0..=Y_RANGE.1).contains(&y)
                && z.abs() <= PARKED_Z;
            inside.then(|| PlacedObject {
                id: ObjectId::try_from(index + 1).unwrap(),
                shape: ShapeKind::from_mesh_name(fields[0]).expect("a catalogue mesh"),
                colour: [1, 2, 3]
                    .map(|i| (fields[i].parse::<f64>().unwrap() * 255.0).round() as u8),
                position: [x, y, z],
                euler_xyz: [number(7), number(8), number(9)],
            })
        })
        .collect()
}

fn ids(objects: &[PlacedObject]) -> Vec<ObjectId> {
    objects.iter().map(|o| o.id).collect()
}

#[test]
fn original_files_load_the_objects_over_the_workspace() {
    let Some(cases) = test_cases_dir() else {
        return;
    };
    for path in original_files(&cases) {
        let text = std::fs::read_to_string(&path).unwrap();
        let expected = objects_in_lines(&text);
        let loaded = load(&path, &OriginalOptions::default());
        assert_eq!(
            ids(&loaded.objects),
            ids(&expected),
            "{}: object ids",
            path.display()
        );
        assert_eq!(loaded.objects, expected, "{}", path.display());
        assert_eq!(
            loaded.goal,
            None,
            "{}: the original format names no goal",
            path.display()
        );
    }
}

#[test]
fn novel_object_files_are_refused_naming_the_mesh_and_line() {
    let Some(cases) = test_cases_dir() else {
        return;
    };
    let files = files_starting_with(&cases.join(PAPER_DIR), "novel-obj-");
    assert_eq!(files.len(), 5);
    for path in files {
        let text = std::fs::read_to_string(&path).unwrap();
        let mesh = text.split_whitespace().next().unwrap();
        let error = Arrangement::read(&path, &OriginalOptions::default())
            .expect_err(&format!("{} names unknown meshes", path.display()));
        let ArrangementError::Line { line, message, .. } = &error else {
            panic!("{}: expected a line error, got {error:?}", path.display());
        };
        assert_eq!(*line, 1, "{error}");
        assert!(message.contains(mesh), "{error} should name `{mesh}`");
        assert!(
            error.to_string().contains(&path.display().to_string()),
            "{error} should name the file"
        );
    }
}

#[test]
fn y_offset_shifts_every_object_by_ten_centimetres() {
    let Some(cases) = test_cases_dir() else {
        return;
    };
    for path in original_files(&cases) {
        let plain = load(&path, &OriginalOptions::default());
        let shifted = load(&path, &OriginalOptions { y_offset: true });
        let pairs: Vec<(&PlacedObject, &PlacedObject)> = plain
            .objects
            .iter()
            .filter_map(|p| {
                shifted
                    .objects
                    .iter()
                    .find(|s| s.id == p.id)
                    .map(|s| (p, s))
            })
            .collect();
        assert!(
            !pairs.is_empty(),
            "{}: no object in both loads",
            path.display()
        );
        for (p, s) in pairs {
            let expected = [p.position[0], p.position[1] + Y_OFFSET, p.position[2]];
            assert_eq!(s.position, expected, "{}: object {}", path.display(), p.id);
            assert_eq!(
                (s.shape, s.colour, s.euler_xyz),
                (p.shape, p.colour, p.euler_xyz)
            );
        }
    }
}

/// A well-formed original-format line.
const GOOD_LINE: &str = "4.obj 0.5 0.5 0.5 -0.5 0.0 0.025 0 0 0";

/// `error` names `file` and `bad_line`, and its message says `says`.
fn assert_line_error(
    error: &ArrangementError,
    file: &str,
    bad_line: usize,
    says: &str,
    what: &str,
) {
    let ArrangementError::Line { line, message, .. } = error else {
        panic!("{what}: expected a line error, got {error:?}");
    };
    assert_eq!(*line, bad_line, "{what}: {error}");
    assert!(
        message.contains(says),
        "{what}: `{error}` should say {says}"
    );
    let prefix = format!("{file}:{bad_line}:");
    assert!(
        error.to_string().starts_with(&prefix),
        "{what}: `{error}` should start with {prefix}"
    );
}

#[test]
fn malformed_original_lines_are_reported_with_their_line() {
    // (what is wrong, the file's text, the bad line, what the message must say)
    let cases = [
        (
            "too few fields",
            format!("{GOOD_LINE}\n4.obj 0.5 0.5 0.5 -0.5 0.0 0.025 0 0\n"),
            2,
            "found 9",
        ),
        (
            "y is not a number",
            format!("{GOOD_LINE}\n{GOOD_LINE}\n4.obj 0.5 0.5 0.5 -0.5 north 0.025 0 0 0\n"),
            3,
            "`y`",
        ),
        (
            "z is not finite",
            format!("{GOOD_LINE}\n4.obj 0.5 0.5 0.5 -0.5 0.0 inf 0 0 0\n"),
            2,
            "`z`",
        ),
        (
            "green above 1",
            format!("{GOOD_LINE}\n4.obj 0.5 1.5 0.5 -0.5 0.0 0.025 0 0 0\n"),
            2,
            "`green`",
        ),
        (
            "unknown mesh",
            format!("{GOOD_LINE}\n{GOOD_LINE}\nteapot.obj 0.5 0.5 0.5 -0.5 0.0 0.025 0 0 0\n"),
            3,
            "`teapot.obj`",
        ),
    ];
    let path = Path::new("bad.txt");
    let options = OriginalOptions::default();
    assert_eq!(
        Arrangement::parse_original(&format!("{GOOD_LINE}\n{GOOD_LINE}\n"), path, &options)
            .expect("good lines load")
            .objects
            .len(),
        2
    );
    for (what, text, bad_line, says) in cases {
        let error = Arrangement::parse_original(&text, path, &options)
            .expect_err(&format!("{what}: should be refused"));
        assert_line_error(&error, "bad.txt", bad_line, says, what);
    }
}

#[test]
fn named_goal_lines_mark_the_goal_and_take_slot_colours() {
    let text = "block 4.obj -0.6 0.0 0.026 0 0 0\n\
                block 1.obj -0.5 5.0 0.026 0 0 0\n\
                red 8.obj -0.5 0.0 0.026 0 0 0\n\
                block 4.obj -0.4 0.0 0.026 0 0 0\n";
    let arrangement =
        Arrangement::parse_original(text, Path::new("named.txt"), &OriginalOptions::default())
            .expect("loads");
    assert_eq!(arrangement.goal, Some(3), "the line not named `block`");
    assert_eq!(
        ids(&arrangement.objects),
        [1, 3, 4],
        "line 2 is off the table"
    );
    for object in &arrangement.objects {
        let slot = usize::from(object.id) - 1;
        assert_eq!(
            object.colour,
            sim::SLOT_COLOURS[slot],
            "object {}",
            object.id
        );
    }
    assert_eq!(
        arrangement.objects[1].shape,
        ShapeKind::from_mesh_name("8.obj").unwrap()
    );
    assert_eq!(arrangement.objects[1].position, [-0.5, 0.0, 0.026]);

    let path = Path::new("goals.txt");
    let options = OriginalOptions::default();
    let cases = [
        (
            "two goals",
            format!("{text}blue 4.obj -0.4 0.1 0.026 0 0 0\n"),
            5,
            "second goal",
        ),
        (
            "goal off the table",
            "block 4.obj -0.6 0.0 0.026 0 0 0\nred 8.obj -0.5 0.9 0.026 0 0 0\n".to_string(),
            2,
            "off the workspace",
        ),
        (
            "x is not a number",
            "red 8.obj west 0.0 0.026 0 0 0\n".to_string(),
            1,
            "`x`",
        ),
    ];
    for (what, text, bad_line, says) in cases {
        let error = Arrangement::parse_original(&text, path, &options)
            .expect_err(&format!("{what}: should be refused"));
        assert_line_error(&error, "goals.txt", bad_line, says, what);
    }
}

/// Every object position of a file, to the millimetre.
fn positions_mm(arrangement: &Arrangement) -> Vec<[i32; 2]> {
    arrangement
        .objects
        .iter()
        .map(|o| [0, 1].map(|i| (o.position[i] * 1000.0).round() as i32))
        .collect()
}

#[test]
fn validation_cases_match_their_originals_and_are_not_challenging_cases() {
    let files = validation_files();
    assert_eq!(files.len(), 5, "{files:?}");
    let challenging: Vec<(PathBuf, Vec<[i32; 2]>)> = challenging_files()
        .into_iter()
        .map(|path| {
            let positions = positions_mm(&load(&path, &OriginalOptions::default()));
            (path, positions)
        })
        .collect();
    let originals = test_cases_dir().map(|cases| cases.join(GRASPING_INVISIBLE_DIR));
    for path in &files {
        let arrangement = load(path, &OriginalOptions::default());
        let goal = arrangement.goal.expect("a validation case names its goal");
        assert!(
            arrangement.objects.iter().any(|o| o.id == goal),
            "{}: goal {goal} on the table",
            path.display()
        );
        // Two of the coordination cases hold five objects of a challenging case each; one
        // object in the same place is a coincidence of the designers' grid.
        let positions = positions_mm(&arrangement);
        for (case, theirs) in &challenging {
            let shared = positions.iter().filter(|p| theirs.contains(p)).count();
            assert!(
                shared <= 1,
                "{}: {shared} objects where {} has them",
                path.display(),
                case.display()
            );
        }
        let Some(dir) = &originals else {
            continue;
        };
        let name = arrangement.name.clone().expect("a name");
        let original_path = dir.join(format!("{name}.txt"));
        let original = load(&original_path, &OriginalOptions::default());
        assert_eq!(arrangement.objects, original.objects, "{}", path.display());
        // The goal, read here: the one line not named `block`.
        let text = std::fs::read_to_string(&original_path).unwrap();
        let goal_lines: Vec<usize> = text
            .lines()
            .enumerate()
            .filter(|(_, line)| line.split_whitespace().next() != Some("block"))
            .map(|(index, _)| index + 1)
            .collect();
        assert_eq!(goal_lines, [usize::from(goal)], "{}", path.display());
    }
}

// ---------------------------------------------------------------------------------------
// Our TOML format.

/// A valid file, each object's lines numbered in the comments of the cases below.
const GOOD_TOML: &str = r#"name = "two blocks"
goal = 2

[[objects]]
id = 1
shape = "cube"
colour = [78, 121, 167]
position = [-0.5, 0.0, 0.025]

[[objects]]
id = 2
shape = "roof"
colour = [89, 161, 79]
position = [-0.6, 0.1, 0.0245]
euler_xyz = [0.0, 1.5708, 0.0]
"#;

#[test]
fn toml_round_trips() {
    let mut arrangements =
        vec![Arrangement::parse_toml(GOOD_TOML, Path::new("good.toml")).unwrap()];
    arrangements.extend(designed_scenes().into_iter().map(|(_, a)| a));
    for arrangement in arrangements {
        let text = arrangement.to_toml();
        let back = Arrangement::parse_toml(&text, Path::new("round-trip.toml"))
            .unwrap_or_else(|e| panic!("{e}\n{text}"));
        assert_eq!(back, arrangement, "{text}");
    }
}

#[test]
fn jitter_shifts_objects_and_turns_them_about_the_vertical() {
    const SHIFT: f32 = 0.001;
    const TURN: f32 = 0.1;
    let arrangement = Arrangement::parse_toml(GOOD_TOML, Path::new("good.toml")).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut largest_turn: f32 = 0.0;
    for _ in 0..20 {
        let jittered = arrangement.jittered(SHIFT, TURN, &mut rng);
        for (before, after) in arrangement.objects.iter().zip(&jittered.objects) {
            let (p, q) = (before.pose(), after.pose());
            let moved = q.translation - p.translation;
            assert!(
                moved.x.abs() <= SHIFT + 1e-6 && moved.y.abs() <= SHIFT + 1e-6 && moved.z == 0.0
            );
            // A turn about the world's vertical leaves every body axis at its height (the
            // roof lies on its side: a turn about its own z would tilt it).
            for axis in [Vector::X, Vector::Y, Vector::Z] {
                let (a, b) = (p.rotation * axis, q.rotation * axis);
                assert!(
                    (a.z - b.z).abs() < 1e-4,
                    "object {}: {a} became {b}",
                    before.id
                );
            }
            let turn = p.rotation.angle_between(q.rotation);
            assert!(
                turn <= TURN + 1e-4,
                "object {} turned {turn} rad",
                before.id
            );
            largest_turn = largest_turn.max(turn);
        }
    }
    assert!(
        largest_turn > TURN / 2.0,
        "the jitter hardly turns: {largest_turn} rad"
    );
}

#[test]
fn a_settled_random_scene_rebuilt_from_its_arrangement_stays_where_it_was() {
    let config = SimConfig::default();
    let (scene, _) = Tabletop::random(&config, 10, 3).unwrap();
    let arrangement = scene.to_arrangement(Some("random-3".into()), Some(2));
    assert_eq!(arrangement.goal, Some(2));
    assert_eq!(arrangement.objects.len(), scene.object_count());
    let mut rebuilt = Tabletop::from_arrangement(&config, &arrangement).unwrap();
    rebuilt.settle();
    for (before, after) in scene.objects().zip(rebuilt.objects()) {
        assert_eq!(
            (before.id, before.kind, before.colour),
            (after.id, after.kind, after.colour)
        );
        let moved = (after.pose.translation - before.pose.translation).length();
        let turned = before.pose.rotation.angle_between(after.pose.rotation);
        // A half-cylinder resting on its curved side rocks by up to two degrees as it
        // settles again (1 kg objects, friction 0.71 on a 0.5 floor, multiplied).
        assert!(
            moved < 0.002 && turned < 0.035,
            "object {} moved {moved} m and turned {turned} rad",
            before.id
        );
    }
}

#[test]
fn malformed_toml_is_reported_with_its_line() {
    // (what is wrong, (text in GOOD_TOML, replacement), the bad line, what the message says)
    let cases = [
        ("unknown shape", ("\"roof\"", "\"teapot\""), 12, "teapot"),
        ("duplicate id", ("id = 2", "id = 1"), 10, "appears twice"),
        ("goal not an object", ("goal = 2", "goal = 9"), 2, "goal 9"),
        ("id 0", ("id = 2", "id = 0"), 10, "id 0"),
        ("syntax error", ("\"roof\"", "roof"), 12, "must be quoted"),
        (
            "unknown field",
            ("euler_xyz", "mass = 0.1\neuler_xyz"),
            15,
            "mass",
        ),
    ];
    let path = Path::new("bad.toml");
    let good = Arrangement::parse_toml(GOOD_TOML, path).expect("the good file loads");
    assert_eq!((good.goal, good.objects.len()), (Some(2), 2));
    for (what, (from, to), bad_line, says) in cases {
        assert_eq!(GOOD_TOML.matches(from).count(), 1, "{what}: ambiguous edit");
        let text = GOOD_TOML.replace(from, to);
        let error = Arrangement::parse_toml(&text, path)
            .expect_err(&format!("{what}: should be refused:\n{text}"));
        assert_line_error(&error, "bad.toml", bad_line, says, what);
    }
}

#[test]
fn challenging_cases_name_the_papers_goals_and_match_the_originals() {
    let files = challenging_files();
    let names: Vec<String> = files
        .iter()
        .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    let expected: Vec<String> = (0..10)
        .map(|n| format!("challenging-{n:02}.toml"))
        .collect();
    assert_eq!(names, expected);
    let originals = test_cases_dir().map(|cases| cases.join(PAPER_DIR));
    for (n, (path, slot)) in files.iter().zip(CHALLENGING_GOAL_SLOTS).enumerate() {
        let arrangement = load(path, &OriginalOptions::default());
        assert_eq!(arrangement.goal, Some(slot + 1), "{}", path.display());
        let Some(dir) = &originals else {
            continue;
        };
        let original = load(
            &dir.join(format!("test-10-obj-{n:02}.txt")),
            &OriginalOptions::default(),
        );
        assert_eq!(arrangement.objects, original.objects, "{}", path.display());
    }
}

// ---------------------------------------------------------------------------------------
// Resting as designed.

/// An object as geometry: its id, where it is, its shape and its lowest point.
struct Solid {
    id: ObjectId,
    pose: Pose,
    shape: SharedShape,
    lowest: f32,
}

impl Solid {
    fn new(id: ObjectId, kind: ShapeKind, pose: Pose) -> Self {
        let parts = kind.parts();
        let lowest = parts
            .iter()
            .flat_map(|p| &p.vertices)
            .map(|&v| pose.transform_point(v).z)
            .fold(f32::INFINITY, f32::min);
        let shape = SharedShape::compound(
            parts
                .iter()
                .map(|p| {
                    (
                        Pose::IDENTITY,
                        SharedShape::convex_hull(&p.vertices).unwrap(),
                    )
                })
                .collect(),
        );
        Self {
            id,
            pose,
            shape,
            lowest,
        }
    }

    fn distance(&self, other: &Solid) -> f32 {
        query::distance(&self.pose, &*self.shape, &other.pose, &*other.shape)
            .expect("compound distances are supported")
            .distance
    }

    fn penetration(&self, other: &Solid) -> f32 {
        query::contact(&self.pose, &*self.shape, &other.pose, &*other.shape, 0.0)
            .expect("compound contacts are supported")
            .map_or(0.0, |c| -c.dist)
    }
}

fn solids(arrangement: &Arrangement) -> Vec<Solid> {
    arrangement
        .objects
        .iter()
        .map(|o| Solid::new(o.id, o.shape, o.pose()))
        .collect()
}

/// What keeps a scene from resting as designed: an object neither on the table nor on a
/// lower object, or two objects overlapping, beyond `REST_TOLERANCE`.
fn resting_problems(solids: &[Solid]) -> Vec<String> {
    let mut problems = Vec::new();
    for s in solids {
        let on_table = s.lowest.abs() <= REST_TOLERANCE;
        let on_another = solids
            .iter()
            .any(|o| o.lowest < s.lowest && s.distance(o) <= REST_TOLERANCE);
        if !(on_table || on_another) {
            problems.push(format!(
                "object {} (lowest point z = {:.4}) rests on nothing",
                s.id, s.lowest
            ));
        }
    }
    for (i, a) in solids.iter().enumerate() {
        for b in &solids[i + 1..] {
            let depth = a.penetration(b);
            if depth > REST_TOLERANCE {
                problems.push(format!(
                    "object {} and object {} overlap by {depth:.4} m",
                    a.id, b.id
                ));
            }
        }
    }
    problems
}

#[test]
fn designed_scenes_rest_on_the_table_or_each_other() {
    for (path, arrangement) in designed_scenes() {
        let problems = resting_problems(&solids(&arrangement));
        assert!(problems.is_empty(), "{}: {problems:#?}", path.display());
    }
}

/// A roof turned a quarter about the horizontal axis across its length (body z): it stands
/// on one end, half its 0.093 m length below its centre.
fn stand_roof_on_end(arrangement: &Arrangement, solids: &mut [Solid]) -> ObjectId {
    let roof = arrangement
        .objects
        .iter()
        .find(|o| o.shape == ShapeKind::Roof)
        .expect("the scene has a roof");
    let pose = roof.pose();
    let axis = Vector::Z.cross(pose.rotation * Vector::Z).normalize();
    let turned = Pose::from_parts(
        pose.translation,
        Rotation::from_axis_angle(axis, FRAC_PI_2) * pose.rotation,
    );
    let solid = solids.iter_mut().find(|s| s.id == roof.id).unwrap();
    *solid = Solid::new(roof.id, roof.shape, turned);
    roof.id
}

/// The second object moved to where the first is.
fn move_into_first(arrangement: &Arrangement, solids: &mut [Solid]) -> ObjectId {
    let [first, second, ..] = &arrangement.objects[..] else {
        panic!("the scene has two objects");
    };
    let pose = Pose::from_parts(first.pose().translation, second.pose().rotation);
    solids[1] = Solid::new(second.id, second.shape, pose);
    second.id
}

#[test]
fn resting_check_flags_objects_out_of_place() {
    type Perturbation = fn(&Arrangement, &mut [Solid]) -> ObjectId;
    // (what is done, how, what the check must then say about the object moved)
    let cases: [(&str, Perturbation, &str); 2] = [
        (
            "roof stood on its end",
            stand_roof_on_end,
            "rests on nothing",
        ),
        ("object moved into another", move_into_first, "overlap"),
    ];
    let (path, arrangement) = designed_scenes()
        .into_iter()
        .find(|(_, a)| a.objects.iter().any(|o| o.shape == ShapeKind::Roof))
        .expect("some designed scene has a roof");
    assert!(resting_problems(&solids(&arrangement)).is_empty());
    for (what, perturb, says) in cases {
        let mut solids = solids(&arrangement);
        let id = perturb(&arrangement, &mut solids);
        let problems = resting_problems(&solids);
        assert!(
            problems
                .iter()
                .any(|p| p.contains(says) && p.contains(&format!("object {id} "))),
            "{}: {what} (object {id}) went unnoticed: {problems:#?}",
            path.display()
        );
    }
}

// ---------------------------------------------------------------------------------------
// Physics takes over.

#[test]
fn designed_scenes_barely_move_when_settled() {
    let config = SimConfig::default();
    let mut failures = Vec::new();
    for (path, arrangement) in designed_scenes() {
        let mut tabletop = Tabletop::from_arrangement(&config, &arrangement)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let report = tabletop.settle();
        if !(report.at_rest && report.removed.is_empty()) {
            failures.push(format!("{}: {report:?}", path.display()));
        }
        for _ in 0..(AFTER_SETTLE_S * config.physics_hz) as u32 {
            tabletop.step();
        }
        let mut largest = (0.0f32, 0);
        for object in &arrangement.objects {
            let moved = tabletop.object(object.id).map_or(f32::INFINITY, |view| {
                (view.pose.translation - Vector::from_array(object.position)).length()
            });
            if moved >= SETTLE_TOLERANCE {
                failures.push(format!(
                    "{}: object {} moved {moved:.4} m",
                    path.display(),
                    object.id
                ));
            } else if moved > largest.0 {
                largest = (moved, object.id);
            }
        }
        eprintln!(
            "{}: at rest after {} steps, then {AFTER_SETTLE_S} s more; largest move {:.4} m (object {})",
            path.display(),
            report.steps,
            largest.0,
            largest.1
        );
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
