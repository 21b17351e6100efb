//! The terminal summary of a stats report: one line per category, the overall line, one per map
//! where the dataset has maps, the read errors, the false-alarm rate of the check, and the verdict.

use super::stats_report::{StatsReport, Status};

/// The terminal summary: one line per category, the overall line, read errors, and the verdict.
pub fn summary_lines(report: &StatsReport) -> Vec<String> {
    let w = crate::validate::name_column_width(report.categories.iter().map(|c| c.name.as_str()));
    let (lo, hi) = (report.law_support[0], report.law_support[1]);
    let mut lines = vec![format!(
        "stats of {} ({} samples, recipe {}, law on [{lo}, {hi}] px, KS alpha {})",
        report.dataset, report.samples, report.recipe, report.ks_alpha
    )];
    lines.extend(report.notes.iter().map(|n| format!("NOTE {n}")));
    lines.extend(report.curation.iter().map(|r| {
        format!(
            "curation round {}: {} of {} scored samples replaced ({}; model {} {}){}",
            r.round,
            r.replaced,
            r.scored,
            r.rule,
            r.model,
            r.model_fingerprint,
            if r.complete {
                ""
            } else {
                " - UNFINISHED: re-run its curate command"
            }
        )
    }));
    lines.extend(report.categories.iter().map(|c| c.line(w)));
    lines.push(report.overall.line(w));
    lines.extend(report.difficulty.iter().map(|d| d.line(w)));
    lines.extend(report.maps.iter().flat_map(|m| m.lines()));
    for e in report.errors.iter().take(10) {
        lines.push(format!("ERROR {e}"));
    }
    if report.errors.len() > 10 {
        lines.push(format!(
            "ERROR ... and {} more unreadable files",
            report.errors.len() - 10
        ));
    }
    lines.push(false_alarm_line(report));
    let failing: Vec<&str> = report
        .categories
        .iter()
        .chain([&report.overall])
        .filter(|c| c.status == Status::Fail)
        .map(|c| c.name.as_str())
        .collect();
    lines.push(if report.pass {
        let tested = report
            .categories
            .iter()
            .filter(|c| c.status == Status::Ok)
            .count();
        format!(
            "verdict: PASS ({tested} of {} categories tested, all follow the law)",
            report.categories.len()
        )
    } else if report.samples == 0 {
        "verdict: FAIL (the dataset has no samples)".to_string()
    } else if failing.is_empty() {
        format!("verdict: FAIL ({} unreadable file(s))", report.errors.len())
    } else {
        format!(
            "verdict: FAIL ({} miss the target{})",
            failing.join(", "),
            if report.errors.is_empty() {
                String::new()
            } else {
                format!("; {} unreadable file(s)", report.errors.len())
            }
        )
    });
    lines
}

/// What a FAIL is worth: how often a dataset that follows its law fails by chance.
fn false_alarm_line(report: &StatsReport) -> String {
    let judged = report
        .categories
        .iter()
        .chain([&report.overall])
        .filter(|c| c.objects.ks_level.is_some())
        .count();
    format!(
        "false alarms: a dataset that follows its law fails the {judged} KS test(s) with probability at most {} (Holm); each gap check at most {}; groups under {} objects: too few samples to judge",
        report.ks_alpha, report.ks_alpha, report.min_objects_to_judge
    )
}
