//! What `eval` prints: the report (also its JSON), the table like the paper's, and `--why`'s
//! account of the failed runs.

use agent::failures::{FailureReport, QBin};
use agent::{CaseMetrics, TestLearning};
use policy::{PolicyConfig, Rule};
use serde::Serialize;

/// One case's figures.
#[derive(Serialize)]
pub(crate) struct CaseRow {
    pub(crate) case: String,
    #[serde(flatten)]
    pub(crate) metrics: CaseMetrics,
    /// With `--why`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) why: Option<FailureReport>,
}

/// An evaluation's figures and the settings that made them (`--json` prints it).
#[derive(Serialize)]
pub(crate) struct EvalReport {
    pub(crate) checkpoint: String,
    /// The checkpoints whose nets acted together with `checkpoint`'s (`--ensemble`).
    pub(crate) ensemble: Vec<String>,
    pub(crate) updates: u64,
    pub(crate) runs_per_case: usize,
    pub(crate) seed: u64,
    pub(crate) mode: policy::Mode,
    /// The policy that acted: its rule, Q* and test-time masks, each at the report's top
    /// level (its exploration settings are the training's: a test acts greedily).
    #[serde(flatten)]
    pub(crate) policy: PolicyConfig,
    /// `--avoid-failed-grasps`: no grasp that picked nothing since the last push made again.
    pub(crate) avoid_failed_grasps: bool,
    /// `--grasp-after-idle-push`: a grasp next after a push that moved nothing.
    pub(crate) grasp_after_idle_push: bool,
    /// `[sim] guarded_push_descent`.
    pub(crate) guarded_push_descent: bool,
    pub(crate) goal_agnostic: bool,
    /// Whether the nets learned during the test (`--learn`), and from what.
    pub(crate) learning: Option<TestLearning>,
    /// The rule random scenes were tested under, where not `rule`.
    pub(crate) random_scene_rule: Option<Rule>,
    pub(crate) cases: Vec<CaseRow>,
    /// The mean over the designed arrangements (random scenes left out); absent without any.
    pub(crate) average: Option<CaseMetrics>,
    /// With `--why`: the designed arrangements' runs together.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) arrangements_why: Option<FailureReport>,
}

pub(crate) fn print_table(report: &EvalReport) {
    let policy = &report.policy;
    println!(
        "{}{} (stage checkpoint after {} updates), {} runs per case, seed {}, {:?}, {:?} rule, Q* {}{}{}{}{}{}{}{}{}{}{}{}{}",
        report.checkpoint,
        if report.ensemble.is_empty() {
            String::new()
        } else {
            format!(", Q maps averaged with {} more nets", report.ensemble.len())
        },
        report.updates,
        report.runs_per_case,
        report.seed,
        report.mode,
        policy.rule,
        policy.q_star,
        if policy.grasp_margin > 0.0 {
            format!(", grasp margin {} mm", 1000.0 * policy.grasp_margin)
        } else {
            String::new()
        },
        policy
            .goal_guard
            .map(|margin| format!(", goal guard {} mm", 1000.0 * margin))
            .unwrap_or_default(),
        policy
            .landing_guard
            .map(|margin| {
                let seen = match (policy.landing_subpixels, policy.landing_retreat) {
                    (1, _) => String::new(),
                    (finer, None) => format!(" seen {finer}x finer"),
                    (finer, Some(back)) => format!(
                        ", pushes onto the goal seen {finer}x finer started up to {} mm back",
                        1000.0 * back
                    ),
                };
                format!(
                    ", jaws landing clear of objects by {} mm{seen}",
                    1000.0 * margin
                )
            })
            .unwrap_or_default(),
        policy
            .grasp_landing_guard
            .map(|margin| {
                format!(
                    ", grasps' open jaws landing clear of objects by {} mm",
                    1000.0 * margin
                )
            })
            .unwrap_or_default(),
        policy
            .squeeze_guard
            .map(|friction| format!(", no grasp squeezing the goal out at friction {friction}"))
            .unwrap_or_default(),
        if policy.view_edge_guard {
            ", no grasp closing along a side of the view the goal reaches"
        } else {
            ""
        },
        if report.avoid_failed_grasps {
            ", no failed grasp repeated"
        } else {
            ""
        },
        if report.grasp_after_idle_push {
            ", a grasp after a push that moved nothing"
        } else {
            ""
        },
        policy
            .push_reach
            .map(|reach| format!(", pushes within {} mm of the goal", 1000.0 * reach))
            .unwrap_or_default(),
        policy
            .free_border
            .map(|free| {
                let once = if policy.free_border_once {
                    " until a grasp fails"
                } else {
                    ""
                };
                format!(", grasp at a border ring at most {free} occupied{once}")
            })
            .unwrap_or_default(),
        if report.guarded_push_descent {
            ", guarded push descent"
        } else {
            ""
        },
        if report.goal_agnostic {
            ", goal-agnostic (clear the table)"
        } else {
            ""
        }
    );
    if let Some(rule) = report.random_scene_rule
        && report.cases.iter().any(|c| c.case.starts_with("random-"))
    {
        println!("random scenes under the {rule:?} rule");
    }
    if let Some(learning) = &report.learning {
        println!(
            "learning during the test: {:?} nets, learning rate {}, a fresh Adam each run",
            learning.trained, learning.learning.learning_rate
        );
    }
    println!(
        "{:18} {:>11} {:>20} {:>14} {:>16}",
        "case", "completion", "grasp success (se)", "motion number", "any object picked"
    );
    let percent = |x: Option<f64>| x.map_or("-".into(), |x| format!("{:.1}%", 100.0 * x));
    let row = |name: &str, m: &CaseMetrics| {
        let se = m
            .grasp_success_se
            .map_or(String::new(), |se| format!(" ({:.1})", 100.0 * se));
        println!(
            "{name:18} {:>11} {:>20} {:>14} {:>16}",
            percent(Some(m.completion)),
            percent(m.grasp_success) + &se,
            m.motion_number.map_or("-".into(), |x| format!("{x:.2}")),
            percent(m.any_object_grasp_success)
        );
    };
    for case in &report.cases {
        row(&case.case, &case.metrics);
    }
    if let Some(average) = &report.average {
        row("arrangements avg", average);
    }
}

/// `--why`'s reports: the arrangements' runs together, then each random case's.
pub(crate) fn print_why(report: &EvalReport) {
    let random = report
        .cases
        .iter()
        .filter(|c| c.case.starts_with("random-"));
    let groups = report
        .arrangements_why
        .as_ref()
        .map(|why| ("arrangements", why))
        .into_iter()
        .chain(random.filter_map(|c| c.why.as_ref().map(|why| (c.case.as_str(), why))));
    for (name, why) in groups {
        println!();
        print_failures(name, why);
    }
}

fn print_failures(name: &str, why: &FailureReport) {
    let share = |n: usize, of: usize| format!("{n} ({:.1}%)", 100.0 * n as f64 / of.max(1) as f64);
    println!(
        "why runs failed, {name}: {} runs, {} complete; incomplete: {} out of attempts, {} goal out of view, {} undecided",
        why.runs, why.complete, why.out_of_attempts, why.goal_lost, why.undecided
    );
    let g = &why.grasps;
    println!(
        "  grasps {}: the goal {}, nothing {}, another object {}; the goal knocked out of view {}, repeats of the failed grasp before {}",
        g.attempts,
        share(g.goal, g.attempts),
        share(g.nothing, g.attempts),
        share(g.other_object, g.attempts),
        g.goal_knocked_off,
        share(g.repeats, g.attempts - g.goal),
    );
    let p = &why.pushes;
    let judged = p.pushes - p.unjudged;
    println!(
        "  pushes {}: raised the goal's grasp Q {}, freed its border {}, both {}, neither {}; not judged {}",
        p.pushes,
        share(p.raised_q, judged),
        share(p.freed_border, judged),
        share(p.both, judged),
        share(p.neither, judged),
        p.unjudged
    );
    let label = |bin: &QBin| match (bin.from, bin.to) {
        (None, Some(to)) => format!("<{to}"),
        (Some(from), None) => format!(">={from}"),
        (Some(from), Some(to)) => format!("{from}-{to}"),
        (None, None) => "all".into(),
    };
    let cells = |f: &dyn Fn(&QBin) -> String| {
        why.reliability
            .iter()
            .map(|b| format!("{:>9}", f(b)))
            .collect::<String>()
    };
    println!("  {:16}{}", "goal grasp Q", cells(&label));
    println!("  {:16}{}", "grasps", cells(&|b| b.grasps.to_string()));
    println!(
        "  {:16}{}",
        "picked the goal",
        cells(&|b| b
            .rate()
            .map_or("-".into(), |r| format!("{:.0}%", 100.0 * r)))
    );
}
