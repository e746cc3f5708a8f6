//! A scene's map seen from above, as `eval map` writes it per scene (`DIR/maps/<scene>.svg`): the
//! objects' ground-truth footprints outlined by what became of them (found, missed, merged into
//! another object's instance, never seen), the listed instances filled by what they are (an
//! object, a duplicate, a false positive), so a person sees in a glance which neighbours folded.

use std::fmt::Write;

use groupforward::recon::boxes::OrientedBox;

use super::score::{InstanceOutcome, InstanceRow, ListedInstance, ObjectRow, Outcome, TruthObject};

/// Pixels per metre of the drawing.
const SCALE: f64 = 80.0;
/// Margin around what is drawn (m).
const MARGIN_M: f64 = 0.5;
/// Width of one legend entry, and the legend's columns (px).
const LEGEND_ENTRY_PX: f64 = 190.0;
const LEGEND_COLUMNS: usize = 4;
/// Height of the legend below the room (px): two rows.
const LEGEND_PX: f64 = 56.0;

fn outcome_style(outcome: Outcome) -> (&'static str, &'static str) {
    match outcome {
        Outcome::Found => ("#1a9850", "found"),
        Outcome::Missed => ("#d73027", "missed"),
        Outcome::Merged => ("#f46d43", "merged into another's instance"),
        Outcome::NotSeen => ("#999999", "never seen"),
    }
}

fn instance_style(outcome: InstanceOutcome) -> (&'static str, &'static str) {
    match outcome {
        InstanceOutcome::Object => ("#4575b4", "instance of an object"),
        InstanceOutcome::Duplicate => ("#984ea3", "duplicate"),
        InstanceOutcome::Unmatched => ("#e7298a", "false positive"),
    }
}

/// The footprint's corners, when the box is finite.
fn corners(b: &OrientedBox) -> Option<[glam::DVec2; 4]> {
    let corners = b.footprint();
    corners.iter().all(|c| c.is_finite()).then_some(corners)
}

/// The top-down SVG of one scene: its `objects` with their `rows` (one per object, any order),
/// and the listed `instances` with their `instance_rows`.
pub fn top_down_svg(
    scene: &str,
    objects: &[TruthObject],
    rows: &[ObjectRow],
    instances: &[ListedInstance],
    instance_rows: &[InstanceRow],
) -> String {
    let boxes = objects
        .iter()
        .map(|o| &o.bbox)
        .chain(instances.iter().map(|i| &i.bbox));
    let points: Vec<glam::DVec2> = boxes.filter_map(corners).flatten().collect();
    let (lo, hi) = points.iter().fold(
        (
            glam::DVec2::splat(f64::INFINITY),
            glam::DVec2::splat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    );
    let (lo, hi) = if points.is_empty() {
        (glam::DVec2::ZERO, glam::DVec2::ONE)
    } else {
        (lo - MARGIN_M, hi + MARGIN_M)
    };
    let (width, height) = ((hi.x - lo.x) * SCALE, (hi.y - lo.y) * SCALE);
    // SVG's y runs down: north (world +y) is up.
    let at = |p: glam::DVec2| ((p.x - lo.x) * SCALE, (hi.y - p.y) * SCALE);
    let polygon = |b: &OrientedBox| -> Option<String> {
        let points: Vec<String> = corners(b)?
            .iter()
            .map(|c| {
                let (x, y) = at(*c);
                format!("{x:.1},{y:.1}")
            })
            .collect();
        Some(points.join(" "))
    };
    let mut svg = String::new();
    let _ = writeln!(
        svg,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{:.0}\" height=\"{:.0}\" \
         font-family=\"sans-serif\" font-size=\"11\">",
        width.max(LEGEND_COLUMNS as f64 * LEGEND_ENTRY_PX + 8.0),
        height + LEGEND_PX
    );
    let _ = writeln!(svg, "<title>{scene}: the map from above</title>");
    let _ = writeln!(
        svg,
        "<rect width=\"{width:.0}\" height=\"{height:.0}\" fill=\"#fafafa\" stroke=\"#ccc\"/>"
    );
    for instance in instances {
        let outcome = instance_rows
            .iter()
            .find(|r| r.instance == instance.id)
            .map_or(InstanceOutcome::Unmatched, |r| r.outcome);
        let (color, _) = instance_style(outcome);
        if let Some(points) = polygon(&instance.bbox) {
            let _ = writeln!(
                svg,
                "<polygon class=\"instance\" points=\"{points}\" fill=\"{color}\" \
                 fill-opacity=\"0.35\" stroke=\"{color}\"><title>{} {}</title></polygon>",
                instance.id, instance.name
            );
        }
    }
    for object in objects {
        let outcome = rows
            .iter()
            .find(|r| r.object == object.id)
            .map_or(Outcome::NotSeen, |r| r.outcome);
        let (color, _) = outcome_style(outcome);
        let dash = if outcome == Outcome::NotSeen {
            " stroke-dasharray=\"4 3\""
        } else {
            ""
        };
        let Some(points) = polygon(&object.bbox) else {
            continue;
        };
        let _ = writeln!(
            svg,
            "<polygon class=\"object\" points=\"{points}\" fill=\"none\" stroke=\"{color}\" \
             stroke-width=\"2\"{dash}/>"
        );
        let (x, y) = at(object.bbox.centre.truncate());
        let _ = writeln!(
            svg,
            "<text x=\"{x:.1}\" y=\"{y:.1}\" text-anchor=\"middle\" fill=\"{color}\">#{} {}</text>",
            object.id, object.class
        );
    }
    let legend: Vec<(&str, &str, bool)> = [
        Outcome::Found,
        Outcome::Missed,
        Outcome::Merged,
        Outcome::NotSeen,
    ]
    .into_iter()
    .map(|o| {
        let (c, l) = outcome_style(o);
        (c, l, false)
    })
    .chain(
        [
            InstanceOutcome::Object,
            InstanceOutcome::Duplicate,
            InstanceOutcome::Unmatched,
        ]
        .into_iter()
        .map(|o| {
            let (c, l) = instance_style(o);
            (c, l, true)
        }),
    )
    .collect();
    for (k, (color, label, filled)) in legend.iter().enumerate() {
        let (x, y) = (
            8.0 + (k % 4) as f64 * 180.0,
            height + 14.0 + (k / 4) as f64 * 20.0,
        );
        let fill = if *filled { *color } else { "none" };
        let _ = writeln!(
            svg,
            "<rect x=\"{x:.0}\" y=\"{:.0}\" width=\"12\" height=\"10\" fill=\"{fill}\" \
             fill-opacity=\"0.5\" stroke=\"{color}\"/><text x=\"{:.0}\" y=\"{y:.0}\">{label}</text>",
            y - 9.0,
            x + 16.0
        );
    }
    svg.push_str("</svg>\n");
    svg
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn object(id: u16, x: f64) -> TruthObject {
        TruthObject {
            id,
            class: "cabinet".into(),
            bbox: OrientedBox {
                centre: DVec3::new(x, 1.0, 0.9),
                size: DVec3::new(0.8, 0.5, 1.8),
                yaw: 0.3,
            },
            pixels: 5000,
        }
    }

    #[test]
    fn every_object_and_instance_is_drawn_with_its_outcome_and_degenerate_boxes_are_left_out() {
        let objects = vec![object(1, 1.0), object(2, 1.8)];
        let merged = ObjectRow {
            outcome: Outcome::Merged,
            ..row(2)
        };
        let rows = vec![row(1), merged];
        let instance = ListedInstance {
            id: "inst_000001".into(),
            name: "cabinet".into(),
            name_score: 0.9,
            observations: 3,
            gaussians: 500,
            bbox: OrientedBox::from_bounds(DVec3::new(0.6, 0.7, 0.0), DVec3::new(2.2, 1.3, 1.8)),
        };
        let nan = ListedInstance {
            id: "inst_000002".into(),
            bbox: OrientedBox {
                centre: DVec3::NAN,
                ..instance.bbox
            },
            ..instance.clone()
        };
        let svg = top_down_svg("s", &objects, &rows, &[instance, nan], &[]);
        assert_eq!(svg.matches("class=\"object\"").count(), 2);
        assert_eq!(
            svg.matches("class=\"instance\"").count(),
            1,
            "the NaN box is left out"
        );
        assert!(svg.contains("#2 cabinet") && svg.contains("merged into another"));
        assert!(svg.contains("#f46d43") && svg.contains("#1a9850"));
        assert!(!svg.contains("NaN") && !svg.contains("inf"));
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        // Nothing at all still makes a picture.
        assert!(top_down_svg("empty", &[], &[], &[], &[]).contains("</svg>"));
    }

    fn row(object: u16) -> ObjectRow {
        ObjectRow {
            scene: "s".into(),
            object,
            class: "cabinet".into(),
            pixels: 5000,
            outcome: Outcome::Found,
            instance: "inst_000001".into(),
            iou: 0.5,
            name: "cabinet".into(),
            name_correct: true,
            centre_error_m: 0.1,
            size_ratio: 1.0,
            trace: Default::default(),
            lost_at: None,
        }
    }
}
