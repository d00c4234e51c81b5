use std::collections::HashSet;
use std::path::Path;

use plots::{Chart, PlotError, Series, draw};

fn run(label: &str, slope: f64) -> Series {
    Series {
        label: label.into(),
        points: (0..200)
            .map(|i| (i as f64, 100.0 * (1.0 - (-slope * i as f64).exp())))
            .collect(),
    }
}

fn success_chart(series: Vec<Series>) -> Chart {
    Chart {
        title: "Goal grasp success".into(),
        x_label: "episode".into(),
        y_label: "success over last 30 (%)".into(),
        series,
        references: vec![],
        y_range: Some((0.0, 100.0)),
    }
}

fn q_chart() -> Chart {
    Chart {
        title: "Mean Q of successful grasps".into(),
        x_label: "update".into(),
        y_label: "mean Q".into(),
        series: vec![Series {
            label: "baseline".into(),
            points: (0..50)
                .map(|i| (i as f64 * 100.0, 0.03 * i as f64))
                .collect(),
        }],
        references: vec![(1.8, "Q*".into())],
        y_range: None,
    }
}

#[test]
fn png_has_the_grid_size_and_is_not_blank() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.png");
    let charts = [
        success_chart(vec![run("baseline", 0.02), run("no relabel", 0.01)]),
        q_chart(),
        success_chart(vec![]),
    ];
    draw(&charts, 2, &path).unwrap();

    let image = image::open(&path).unwrap().to_rgb8();
    // Three panels two wide: two columns, two rows.
    assert_eq!(image.dimensions(), (2 * 640, 2 * 420));
    let colours: HashSet<_> = image.pixels().map(|p| p.0).collect();
    // Antialiased text and several curve colours, not a flat fill.
    assert!(colours.len() > 20, "only {} colours", colours.len());
}

#[test]
fn svg_names_title_axes_and_every_series() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.svg");
    let charts = [
        success_chart(vec![run("baseline", 0.02), run("no relabel", 0.01)]),
        q_chart(),
    ];
    draw(&charts, 1, &path).unwrap();

    let svg = std::fs::read_to_string(&path).unwrap();
    for text in [
        "Goal grasp success",
        "episode",
        "success over last 30 (%)",
        "baseline",
        "no relabel",
        "Mean Q of successful grasps",
        "update",
        "mean Q",
        "Q*",
    ] {
        assert!(svg.contains(&format!(">\n{text}\n<")), "{text:?} missing");
    }
}

#[test]
fn text_is_escaped_in_svg() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("escaped.svg");
    let mut chart = q_chart();
    chart.title = "loss < 1 & falling".into();
    draw(&[chart], 1, &path).unwrap();
    let svg = std::fs::read_to_string(&path).unwrap();
    assert!(svg.contains("loss &lt; 1 &amp; falling"));
}

#[test]
fn unknown_extension_is_an_error_naming_the_file() {
    for name in ["curves.pdf", "curves"] {
        let path = Path::new(name);
        let error = draw(&[q_chart()], 1, path).unwrap_err();
        assert!(
            matches!(error, PlotError::UnknownFormat { .. }),
            "{error:?}"
        );
        assert!(error.to_string().contains(name), "{error}");
        assert!(!path.exists());
    }
}

#[test]
fn no_charts_is_an_error_naming_the_file() {
    let error = draw(&[], 2, Path::new("nothing.svg")).unwrap_err();
    assert!(matches!(error, PlotError::NoCharts { .. }), "{error:?}");
    assert!(error.to_string().contains("nothing.svg"));
}

#[test]
fn unwritable_path_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["plot.svg", "plot.png"] {
        let path = dir.path().join("missing").join(name);
        let error = draw(&[q_chart()], 1, &path).unwrap_err();
        assert!(
            error.to_string().contains(&*path.to_string_lossy()),
            "{error}"
        );
    }
}

#[test]
fn empty_and_degenerate_data_draw_without_panicking() {
    let dir = tempfile::tempdir().unwrap();
    let charts = [
        Chart::default(),
        success_chart(vec![Series::default()]),
        Chart {
            series: vec![Series {
                label: "one point".into(),
                points: vec![(3.0, 3.0)],
            }],
            ..Chart::default()
        },
        Chart {
            series: vec![Series {
                label: "diverged".into(),
                points: vec![(0.0, f64::NAN), (1.0, f64::INFINITY), (f64::NAN, 2.0)],
            }],
            references: vec![(f64::NAN, "nan".into()), (1.8, "Q*".into())],
            y_range: Some((5.0, 1.0)),
            ..Chart::default()
        },
        Chart {
            series: vec![Series {
                label: "flat".into(),
                points: (0..10).map(|i| (i as f64, 0.5)).collect(),
            }],
            ..Chart::default()
        },
    ];
    for name in ["empty.svg", "empty.png"] {
        let path = dir.path().join(name);
        draw(&charts, 0, &path).unwrap();
        draw(&charts, 100, &path).unwrap();
    }
    let svg = std::fs::read_to_string(dir.path().join("empty.svg")).unwrap();
    assert!(svg.contains(">\nno data\n<"));
}
