//! What the benchmarks share: synthetic map fixtures and the SVG charts they write.

use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use groupforward::frame::{Keyframe, MeasuredDepth, WindowView};
use groupforward::graph::SceneMap;
use groupforward::model::reconstruction::resized_camera;
use groupforward::recon::gaussians::Gaussians;
use groupforward::recon::raster::{render, RasterSettings};

/// A cube of Gaussians (`side`³ on a 4 cm grid) centred at `center`.
pub(crate) fn cube(center: glam::Vec3, side: usize) -> groupforward::recon::gaussians::Gaussians {
    let mut g = groupforward::recon::gaussians::Gaussians::with_dims(0, 0);
    let half = side as f32 * 0.02;
    for i in 0..side {
        for j in 0..side {
            for k in 0..side {
                let offset = glam::Vec3::new(i as f32, j as f32, k as f32) * 0.04;
                g.push(
                    center - glam::Vec3::splat(half) + offset,
                    0.9,
                    glam::Vec3::splat(0.02),
                    glam::Quat::IDENTITY,
                    glam::Vec3::splat(0.5),
                    &[],
                    &[],
                );
            }
        }
    }
    g
}

/// Four 128 × 96 keyframes looking along +y over the benchmarks' instance grid (1 m pitch, 25 a
/// row), with far depth (every instance counts as seen).
pub(crate) fn bench_views() -> Result<Vec<groupforward::frame::WindowView>> {
    use groupforward::frame::{Keyframe, WindowView};
    use groupforward::recon::camera::Camera;
    use groupforward::recon::Rigid;
    let camera = Camera::from_fov(128, 96, 1.5)?;
    Ok((0..4)
        .map(|k| WindowView {
            keyframe: Keyframe {
                stamp_nanos: k as i64,
                camera,
                world_from_camera: Rigid::new(
                    glam::DQuat::from_rotation_x(-std::f64::consts::FRAC_PI_2),
                    glam::DVec3::new(12.0, -5.0, 1.0 + k as f64 * 0.01),
                ),
            },
            depth: vec![100.0; 128 * 96],
            depth_noise_at_1m: None,
        })
        .collect())
}

/// A linear chart of percentages (0-100 on y) as SVG: one series per (name, points).
pub(crate) fn percent_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    series: &[(&str, Vec<(f64, f64)>)],
) -> Result<()> {
    use plotters::prelude::*;
    let x1 = series
        .iter()
        .flat_map(|(_, s)| s.iter().map(|p| p.0))
        .fold(1.0f64, f64::max);
    let root = SVGBackend::new(path, (720, 420)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..x1, 0.0..100.0)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .light_line_style(WHITE)
        .x_desc(x_label)
        .y_desc("%")
        .draw()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    draw_lines(&mut chart, series)?;
    root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(())
}

/// A log-log line chart as SVG: one series per (name, points).
pub(crate) fn line_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[(&str, Vec<(f64, f64)>)],
) -> Result<()> {
    use plotters::prelude::*;
    let points = series.iter().flat_map(|(_, s)| s.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
    for &(x, y) in points.filter(|(x, y)| x.is_finite() && y.is_finite() && *x > 0.0 && *y > 0.0) {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !(x0 < x1 && y0 <= y1) {
        return Ok(());
    }
    let root = SVGBackend::new(path, (720, 420)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(
            (x0 * 0.8..x1 * 1.25).log_scale(),
            (y0 * 0.5..y1 * 2.0).log_scale(),
        )
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .light_line_style(WHITE)
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_label_formatter(&|y| format!("{y}"))
        .x_desc(x_label)
        .y_desc(y_label)
        .draw()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    // A log axis has no place for zero or below.
    let positive: Vec<(&str, Vec<(f64, f64)>)> = series
        .iter()
        .map(|(name, data)| {
            let kept = data
                .iter()
                .copied()
                .filter(|(_, y)| y.is_finite() && *y > 0.0)
                .collect();
            (*name, kept)
        })
        .collect();
    draw_lines(&mut chart, &positive)?;
    root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(())
}

/// Each series as a line with its points marked, and the legend.
fn draw_lines<'a, X, Y>(
    chart: &mut plotters::prelude::ChartContext<
        'a,
        plotters::prelude::SVGBackend<'a>,
        plotters::prelude::Cartesian2d<X, Y>,
    >,
    series: &[(&str, Vec<(f64, f64)>)],
) -> Result<()>
where
    X: plotters::coord::ranged1d::Ranged<ValueType = f64>,
    Y: plotters::coord::ranged1d::Ranged<ValueType = f64>,
{
    use plotters::prelude::*;
    for (i, (name, data)) in series.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        chart
            .draw_series(LineSeries::new(data.clone(), color.stroke_width(2)))
            .map_err(|e| anyhow::anyhow!("{e}"))?
            .label(*name)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
            });
        chart
            .draw_series(data.iter().map(|p| Circle::new(*p, 3, color.filled())))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(())
}

/// The bench's views as a 320 × 240 depth sensor measures them (the map's depth rendered there):
/// answers' and published masks are cut by them, at that resolution, as on a robot.
pub(crate) fn sensor_depths(map: &SceneMap, views: &[WindowView]) -> Vec<Arc<MeasuredDepth>> {
    let mut all = Gaussians::with_dims(0, 0);
    for instance in &map.instances {
        all.extend_geometry(&instance.gaussians);
    }
    views
        .iter()
        .filter_map(|v| {
            let camera = resized_camera(&v.keyframe.camera, 320, 240);
            let world_from_camera = v.keyframe.world_from_camera;
            let rendered = render(
                &all,
                &[],
                0,
                &camera,
                &world_from_camera.inverse(),
                &RasterSettings::default(),
            )
            .ok()?;
            let depth = rendered
                .depth
                .iter()
                .map(|d| if *d > 0.0 { *d } else { f32::NAN })
                .collect();
            Some(Arc::new(MeasuredDepth::new(
                Keyframe {
                    stamp_nanos: v.keyframe.stamp_nanos,
                    camera,
                    world_from_camera,
                },
                depth,
                None,
            )))
        })
        .collect()
}
