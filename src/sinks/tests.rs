use serde_json::{Value, json};

use super::json::{RecordWriter, jump_schema, push_f64, rule_indices, sample_schema};
use super::plot::{Figure, Panel, Series};
use super::*;
use crate::layout::{Entry, Field, Layout, Shape};

fn field(name: &str, shape: Shape, offset: usize) -> Field {
    Field {
        name: name.into(),
        shape,
        offset,
    }
}

/// h (scalar), x (vector 2), P (2×2), agent family of 2 with xhat (vector 2) and s (scalar).
fn rich_layout() -> (Layout, usize) {
    let agent = |base: usize| {
        vec![
            field("xhat", Shape::Vector(2), base),
            field("s", Shape::Scalar, base + 2),
        ]
    };
    let layout = Layout {
        entries: vec![
            Entry::Field(field("h", Shape::Scalar, 0)),
            Entry::Field(field("x", Shape::Vector(2), 1)),
            Entry::Field(field("P", Shape::Matrix { rows: 2, cols: 2 }, 3)),
            Entry::Family {
                name: "agent".into(),
                labels: vec!["1".into(), "2".into()],
                members: vec![agent(7), agent(10)],
            },
        ],
    };
    (layout, 13)
}

#[test]
fn layouts_are_checked_against_their_dimension() {
    let (layout, dim) = rich_layout();
    check_layout(&layout, dim, "state").unwrap();
    let short = check_layout(&layout, dim - 1, "state").unwrap_err();
    assert!(short.to_string().contains("agent[2].s"), "{short}");
    // Components a layout leaves out are not logged (hidden timers, `log` selections).
    check_layout(&layout, dim + 1, "state").unwrap();
    let mut twice = layout.clone();
    twice
        .entries
        .push(Entry::Field(field("again", Shape::Scalar, 0)));
    let e = check_layout(&twice, dim, "state").unwrap_err();
    assert!(e.to_string().contains("covered twice"), "{e}");
}

#[test]
fn records_follow_the_layout_shapes() {
    let (layout, dim) = rich_layout();
    let x: Vec<f64> = (0..dim).map(|k| k as f64 + 0.5).collect();
    let mut out = Vec::new();
    RecordWriter::new(&layout, &[]).sample(&mut out, HybridTime::new(0.25, 3), &x);
    let v: Value = serde_json::from_slice(&out).unwrap();
    // Compact, fields in layout order, shortest round-trip numbers.
    assert_eq!(
        String::from_utf8(out).unwrap(),
        r#"{"t":0.25,"j":3,"h":0.5,"x":[1.5,2.5],"P":{"rows":2,"cols":2,"data":[3.5,4.5,5.5,6.5]},"agent":[{"xhat":[7.5,8.5],"s":9.5},{"xhat":[10.5,11.5],"s":12.5}]}"#
    );
    assert_eq!(
        v,
        json!({
            "t": 0.25, "j": 3, "h": 0.5, "x": [1.5, 2.5],
            "P": {"rows": 2, "cols": 2, "data": [3.5, 4.5, 5.5, 6.5]},
            "agent": [{"xhat": [7.5, 8.5], "s": 9.5}, {"xhat": [10.5, 11.5], "s": 12.5}]
        })
    );
}

#[test]
fn jump_records_carry_rule_index_pre_and_post() {
    let layout = Layout::scalars(&["h", "v"]);
    let rules: Vec<String> = ["a", "b", "c", "d", "transmit[2]"].map(String::from).into();
    let at = HybridTime::new(1.5, 0);
    // By default without the states.
    let mut out = Vec::new();
    RecordWriter::new(&layout, &rules).jump(&mut out, at, 4, "", &[0.0, -3.0], &[0.0, 2.4]);
    assert_eq!(
        String::from_utf8(out).unwrap(),
        r#"{"t":1.5,"j":0,"rule":"transmit[2]","rule_id":4,"index":[2]}"#
    );
    let writer = RecordWriter::new(&layout, &rules).with_jump_states(true);
    let mut out = Vec::new();
    writer.jump(&mut out, at, 4, "", &[0.0, -3.0], &[0.0, 2.4]);
    let v: Value = serde_json::from_slice(&out).unwrap();
    assert_eq!(
        String::from_utf8(out).unwrap(),
        r#"{"t":1.5,"j":0,"rule":"transmit[2]","rule_id":4,"index":[2],"pre":{"h":0.0,"v":-3.0},"post":{"h":0.0,"v":2.4}}"#
    );
    // A rule the writer does not know is written under the given name.
    let mut other = Vec::new();
    writer.jump(&mut other, at, 7, "#7", &[0.0, -3.0], &[0.0, 2.4]);
    let other: Value = serde_json::from_slice(&other).unwrap();
    assert_eq!(
        (other["rule"].as_str(), other["rule_id"].as_u64()),
        (Some("#7"), Some(7))
    );
    assert_eq!(
        v,
        json!({"t": 1.5, "j": 0, "rule": "transmit[2]", "rule_id": 4, "index": [2],
               "pre": {"h": 0.0, "v": -3.0}, "post": {"h": 0.0, "v": 2.4}})
    );
    assert_eq!(rule_indices("edge[1, 3]"), Some(vec![1, 3]));
    assert_eq!(rule_indices("impact"), None);
    assert_eq!(rule_indices("odd[i]"), None);
}

#[test]
fn families_of_every_form_and_empty_layouts_are_written() {
    let member = |shape, offset| vec![field("", shape, offset)];
    let family = |name: &str, members: Vec<Vec<Field>>| Entry::Family {
        name: name.into(),
        labels: (1..=members.len()).map(|k| k.to_string()).collect(),
        members,
    };
    let layout = Layout {
        entries: vec![
            family(
                "z",
                vec![member(Shape::Scalar, 0), member(Shape::Scalar, 1)],
            ),
            family("xh", vec![member(Shape::Vector(2), 2)]),
            family(
                "m",
                vec![
                    member(Shape::Matrix { rows: 1, cols: 2 }, 4),
                    member(Shape::Vector(1), 6),
                ],
            ),
        ],
    };
    let x: Vec<f64> = (0..7).map(f64::from).collect();
    let mut out = Vec::new();
    RecordWriter::new(&layout, &[]).sample(&mut out, HybridTime::new(0.0, 0), &x);
    assert_eq!(
        String::from_utf8(out).unwrap(),
        r#"{"t":0.0,"j":0,"z":[0.0,1.0],"xh":[{"data":[2.0,3.0]}],"m":[{"rows":1,"cols":2,"data":[4.0,5.0]},{"rows":1,"cols":1,"data":[6.0]}]}"#
    );
    let mut empty = Vec::new();
    RecordWriter::new(&Layout::default(), &[]).sample(&mut empty, HybridTime::new(2.5, 7), &[]);
    assert_eq!(empty, br#"{"t":2.5,"j":7}"#);
}

#[test]
fn numbers_are_written_in_shortest_round_trip_form() {
    let cases = [
        (f64::EPSILON, "2.220446049250313e-16"),
        (0.1 + 0.2, "0.30000000000000004"),
        (1e300, "1e+300"),
        (-0.0, "-0.0"),
        (5e-324, "5e-324"),
        (123456.0, "123456.0"),
    ];
    for (v, text) in cases {
        let mut out = Vec::new();
        push_f64(&mut out, v);
        assert_eq!(std::str::from_utf8(&out).unwrap(), text);
        let mut buf = zmij::Buffer::new();
        assert_eq!(super::csv::number_text(v, &mut buf), text);
        let back: f64 = text.parse().unwrap();
        assert_eq!(back.to_bits(), v.to_bits());
    }
    let mut buf = zmij::Buffer::new();
    assert_eq!(super::csv::number_text(f64::NAN, &mut buf), "NaN");
    assert_eq!(super::csv::number_text(f64::NEG_INFINITY, &mut buf), "-inf");
}

#[test]
fn log_filter_hides_jumps_of_unlogged_rules() {
    // Rule 0 logged, rule 1 (a redraw) not.
    let mut f = LogFilter::new(&[RuleLog::Full, RuleLog::Off], Decimation::all());
    let (at, post) = (HybridTime::new(1.0, 0), HybridTime::new(1.0, 1));
    // A jump of rule 1 alone: nothing written until the post-jump sample,
    // then the held pre-jump sample as a flow sample.
    assert_eq!(
        f.route_sample(at, &[1.0, 2.0], SampleKind::PreJump),
        Route::Nothing
    );
    assert_eq!(f.route_jump(1), (false, None));
    assert_eq!(
        f.route_sample(post, &[0.0, 0.0], SampleKind::PostJump),
        Route::Held(at)
    );
    assert_eq!(f.take_held(), [1.0, 2.0]);
    // Rules 1 and 0 in one jump: the pre-jump sample is written before the
    // first logged record, once; the post-jump sample is written.
    assert_eq!(
        f.route_sample(at, &[3.0, 4.0], SampleKind::PreJump),
        Route::Nothing
    );
    assert_eq!(f.route_jump(1), (false, None));
    assert_eq!(f.route_jump(0), (true, Some(at)));
    assert_eq!(f.route_jump(0), (true, None));
    assert_eq!(
        f.route_sample(post, &[5.0, 6.0], SampleKind::PostJump),
        Route::Sample(SampleKind::PostJump)
    );
    // A run that ends after a held sample keeps it.
    assert_eq!(
        f.route_sample(at, &[5.0, 6.0], SampleKind::PreJump),
        Route::Nothing
    );
    assert_eq!(f.take_unfinished(), Some((at, vec![5.0, 6.0])));
    // Without unlogged rules nothing is held.
    let mut all = LogFilter::new(&[RuleLog::Full, RuleLog::Full], Decimation::all());
    assert_eq!(
        all.route_sample(at, &[1.0], SampleKind::PreJump),
        Route::Sample(SampleKind::PreJump)
    );
    assert_eq!(all.route_jump(1), (true, None));
    assert_eq!(
        all.route_sample(post, &[1.0], SampleKind::PostJump),
        Route::Sample(SampleKind::PostJump)
    );
}

#[test]
fn log_filter_writes_a_marked_rules_record_without_its_samples() {
    // Rule 0 logged in full, rule 1 marked, rule 2 off.
    let mut f = LogFilter::new(
        &[RuleLog::Full, RuleLog::Mark, RuleLog::Off],
        Decimation::all(),
    );
    let (at, post) = (HybridTime::new(1.0, 0), HybridTime::new(1.0, 1));
    // A marked jump alone: its record, no pre-jump sample before it; the
    // held pre-jump sample becomes a flow sample, the post-jump one is
    // dropped.
    assert_eq!(
        f.route_sample(at, &[1.0, 2.0], SampleKind::PreJump),
        Route::Nothing
    );
    assert_eq!(f.route_jump(2), (false, None));
    assert_eq!(f.route_jump(1), (true, None));
    assert_eq!(
        f.route_sample(post, &[0.0, 0.0], SampleKind::PostJump),
        Route::Held(at)
    );
    assert_eq!(f.take_held(), [1.0, 2.0]);
    // With a rule logged in full in the same jump, the jump is written as
    // usual, the marked rule's record among the others.
    let post2 = HybridTime::new(1.0, 2);
    assert_eq!(
        f.route_sample(post, &[3.0, 4.0], SampleKind::PreJump),
        Route::Nothing
    );
    assert_eq!(f.route_jump(0), (true, Some(post)));
    assert_eq!(f.route_jump(1), (true, None));
    assert_eq!(
        f.route_sample(post2, &[5.0, 6.0], SampleKind::PostJump),
        Route::Sample(SampleKind::PostJump)
    );
    // Marks alone (nothing off) still hold samples.
    let mut m = LogFilter::new(&[RuleLog::Mark], Decimation::all());
    assert_eq!(
        m.route_sample(at, &[1.0], SampleKind::PreJump),
        Route::Nothing
    );
    assert_eq!(m.route_jump(0), (true, None));
    assert_eq!(
        m.route_sample(post, &[2.0], SampleKind::PostJump),
        Route::Held(at)
    );
}

#[test]
fn rule_logs_combine_full_before_marks() {
    assert_eq!(
        RuleLog::combine(&[true, false, false, true], &[true, true, false, false]),
        [RuleLog::Full, RuleLog::Mark, RuleLog::Off, RuleLog::Full]
    );
    let mut info = RunInfo::new("m", &["x"], &["a", "b", "c"]);
    info.logged_rules = vec![RuleLog::Mark, RuleLog::Full];
    assert_eq!(info.logged_rule_names(), ["b", "c"]);
    assert_eq!(info.marked_rule_names(), ["a"]);
}

#[test]
fn log_filter_copies_a_held_sample_only_if_the_decimation_keeps_it() {
    // Flow samples at most every 0.5: redraws every 0.2 give one flow
    // sample in three.
    let mut f = LogFilter::new(
        &[RuleLog::Full, RuleLog::Off],
        Decimation::all().dt(Some(0.5)),
    );
    let start = HybridTime::new(0.0, 0);
    assert_eq!(
        f.route_sample(start, &[0.0], SampleKind::Initial),
        Route::Sample(SampleKind::Initial)
    );
    let mut written = Vec::new();
    for k in 1..=6 {
        let (at, post) = (
            HybridTime::new(0.2 * k as f64, k - 1),
            HybridTime::new(0.2 * k as f64, k),
        );
        assert_eq!(
            f.route_sample(at, &[k as f64], SampleKind::PreJump),
            Route::Nothing
        );
        assert_eq!(f.route_jump(1), (false, None));
        if let Route::Held(pre) = f.route_sample(post, &[-1.0], SampleKind::PostJump) {
            let held = f.take_held();
            written.push((pre, held.clone()));
            f.give_back(held);
        }
    }
    assert_eq!(
        written,
        [
            (HybridTime::new(0.6000000000000001, 2), vec![3.0]),
            (HybridTime::new(1.2000000000000002, 5), vec![6.0])
        ]
    );
    // A sample the decimation drops is not kept for the end of the run
    // either; one it keeps is.
    assert_eq!(
        f.route_sample(HybridTime::new(1.3, 6), &[7.0], SampleKind::PreJump),
        Route::Nothing
    );
    assert_eq!(f.take_unfinished(), None);
    assert_eq!(
        f.route_sample(HybridTime::new(1.8, 6), &[8.0], SampleKind::PreJump),
        Route::Nothing
    );
    assert_eq!(
        f.take_unfinished(),
        Some((HybridTime::new(1.8, 6), vec![8.0]))
    );
    // A logged jump writes its pre-jump sample whatever the decimation.
    assert_eq!(
        f.route_sample(HybridTime::new(1.9, 6), &[9.0], SampleKind::PreJump),
        Route::Nothing
    );
    assert_eq!(f.route_jump(0), (true, Some(HybridTime::new(1.9, 6))));
}

/// Schemas use no `$ref`, no unions and no arrays of arrays (what Foxglove
/// can address with message paths).
#[test]
fn schemas_stay_in_the_foxglove_subset() {
    let (layout, _) = rich_layout();
    for schema in [
        sample_schema("S", &layout),
        jump_schema("J", &layout, false),
        jump_schema("J", &layout, true),
        super::json::log_schema(),
    ] {
        assert_foxglove_subset(&schema, false);
    }
}

fn assert_foxglove_subset(s: &Value, inside_array: bool) {
    let obj = s.as_object().expect("a schema is an object");
    for banned in ["$ref", "oneOf", "anyOf", "allOf"] {
        assert!(!obj.contains_key(banned), "{banned} in {s}");
    }
    let ty = obj["type"].as_str().expect("one type, no unions");
    if inside_array {
        assert_ne!(ty, "array", "array of arrays: {s}");
    }
    if let Some(props) = obj.get("properties") {
        for p in props.as_object().unwrap().values() {
            assert_foxglove_subset(p, false);
        }
    }
    if let Some(items) = obj.get("items") {
        assert_foxglove_subset(items, true);
    }
}

#[test]
fn decimation_keeps_jump_and_end_samples() {
    let mut d = Decimator::new(Decimation::all().every(3));
    let kinds = [
        SampleKind::Initial,
        SampleKind::Flow,
        SampleKind::Flow,
        SampleKind::Flow, // 3rd flow sample: kept
        SampleKind::Flow,
        SampleKind::PreJump,
        SampleKind::PostJump,
        SampleKind::Flow,
        SampleKind::Final,
    ];
    let kept: Vec<bool> = kinds
        .iter()
        .enumerate()
        .map(|(k, &kind)| d.keep(HybridTime::new(k as f64, 0), kind))
        .collect();
    assert_eq!(
        kept,
        [true, false, false, true, false, true, true, false, true]
    );

    let mut d = Decimator::new(Decimation::all().dt(Some(0.5)));
    let ts = [0.0, 0.2, 0.4, 0.6, 0.8, 1.2];
    let kept: Vec<bool> = ts
        .iter()
        .enumerate()
        .map(|(k, &t)| {
            let kind = if k == 0 {
                SampleKind::Initial
            } else {
                SampleKind::Flow
            };
            d.keep(HybridTime::new(t, 0), kind)
        })
        .collect();
    assert_eq!(kept, [true, false, false, true, false, true]);

    assert!(Decimation::all().every(0).validate().is_err());
    assert!(Decimation::all().dt(Some(-1.0)).validate().is_err());
    assert!(Decimation::all().dt(Some(f64::NAN)).validate().is_err());
}

#[test]
fn tally_counts_jumps_per_rule_name() {
    let mut t = Tally::new(2);
    t.sample(HybridTime::new(0.0, 0));
    t.jump(1);
    t.jump(1);
    t.jump(0);
    t.sample(HybridTime::new(2.0, 3));
    let names = vec!["a".to_string(), "b".to_string()];
    assert_eq!(t.total_jumps(), 3);
    assert_eq!(
        t.per_rule(&names).into_iter().collect::<Vec<_>>(),
        [("a".to_string(), 1), ("b".to_string(), 2)]
    );
    assert_eq!(t.start, Some(HybridTime::new(0.0, 0)));
    assert_eq!(t.end, Some(HybridTime::new(2.0, 3)));
}

#[test]
fn hybrid_series_split_at_jumps() {
    let samples = [
        (HybridTime::new(0.0, 0), 1.0),
        (HybridTime::new(0.5, 0), 0.0),
        (HybridTime::new(0.5, 1), 0.8),
        (HybridTime::new(1.0, 1), 0.1),
    ];
    let s = Series::hybrid("v", &samples);
    assert_eq!(
        s.pieces,
        vec![vec![(0.0, 1.0), (0.5, 0.0)], vec![(0.5, 0.8), (1.0, 0.1)]]
    );
    assert_eq!(s.connectors, vec![[(0.5, 0.0), (0.5, 0.8)]]);
}

#[test]
fn figures_render_linear_and_log_panels() {
    let e: Vec<(f64, f64)> = (0..20)
        .map(|k| (k as f64, if k == 5 { 0.0 } else { (-(k as f64)).exp() }))
        .collect();
    let svg = Figure::new()
        .panel(
            Panel::new("decay")
                .x_label("t")
                .y_label("|e|")
                .log_y(true)
                .series(Series::line("|e|", e.clone())),
        )
        .panel(Panel::new("sweep").series(Series::points("delta", e)))
        .panel(Panel::new("empty"))
        .to_svg_string()
        .unwrap();
    assert!(svg.starts_with("<svg"));
    for text in ["decay", "sweep", "empty", "|e|", "delta"] {
        assert!(svg.contains(text), "{text} missing");
    }
    // The log panel skipped the zero: no NaN coordinates anywhere.
    assert!(!svg.contains("NaN") && !svg.contains("inf"));
}

/// An axis of the jump count j is labelled with whole numbers (`5`, not `5.0`), on the x axis
/// (`jumps` plots) and the y axis (`domain` plots); ticks between two whole numbers get none.
#[test]
fn j_axes_have_whole_number_labels() {
    // The texts of the SVG's `<text>` elements.
    let texts = |svg: &str| -> Vec<String> {
        svg.split("<text")
            .skip(1)
            .filter_map(|s| {
                let body = &s[s.find('>')? + 1..];
                Some(body[..body.find("</text>")?].trim().to_string())
            })
            .collect()
    };
    // j from 0 to 7 against values in [0.123, 0.13], whose labels are never whole numbers.
    let values: Vec<(f64, f64)> = (0..8)
        .map(|j| (j as f64, 0.123 + 0.001 * j as f64))
        .collect();
    let swapped: Vec<(f64, f64)> = values.iter().map(|&(j, v)| (v, j)).collect();
    for (panel, label) in [
        (
            Panel::new("jumps")
                .x_label("j")
                .x_integers(true)
                .series(Series::line("v", values)),
            "x",
        ),
        (
            Panel::new("domain")
                .y_label("j")
                .y_integers(true)
                .series(Series::line("v", swapped)),
            "y",
        ),
    ] {
        let svg = Figure::new().panel(panel).to_svg_string().unwrap();
        let labels = texts(&svg);
        let numbers: Vec<&String> = labels.iter().filter(|t| t.parse::<f64>().is_ok()).collect();
        let whole: Vec<&&String> = numbers.iter().filter(|t| !t.contains('.')).collect();
        assert!(whole.len() >= 3, "{label}: {numbers:?}");
        assert!(
            !numbers.iter().any(|t| t.ends_with(".0")),
            "{label}: {numbers:?}"
        );
    }
}
